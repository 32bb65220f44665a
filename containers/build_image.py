"""Build the antalate container image with nothing but package registries (PyPI, a Debian mirror).

    sudo .venv/bin/python containers/build_image.py [--arch amd64|arm64] [--tag antalate:0.1.0]
                                      [--extras tello,...] [--base REF] [--wheel antalate-*.whl]
                                      [--podman-opt=--root=DIR ...]

1. the wheelhouse: antalate's wheel (built from this checkout unless ``--wheel``) and every
   dependency's wheel for the target (CPython 3.11, glibc Linux, the architecture), with the
   extras asked for (none by default: MAVLink and sim vehicles; ``--extras tello`` for the Tello
   variant), fetched by ``pip download`` on this host, less ``opencv-python`` and, unless the plot
   extra is asked for, ``pillow`` (see the Containerfile);
2. the base: ``--base REF`` as given (e.g. ``docker.io/library/python:3.11-slim`` where a registry
   is reachable), else Debian bookworm made by ``mmdebstrap`` (variant essential + python3,
   python3-venv, ca-certificates and the libraries the wheels link to; no documentation; merged
   /usr by mmdebstrap's hook rather than usrmerge, which needs perl) and ``podman import``-ed as
   ``localhost/antalate-base:bookworm-ARCH``. A foreign architecture needs qemu-user-static with
   binfmt_misc, for mmdebstrap and for the build's RUN step;
3. ``podman build`` of containers/Containerfile (docker format: OCI images cannot carry a
   HEALTHCHECK), the build step in a chroot, never pulling a ``localhost/`` base.

Prints the image's size. Tests import this module (tests/containers/).
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
PYTHON_VERSION = "3.11"  # Debian bookworm's python3, and the stock base's tag
DEBIAN_SUITE = "bookworm"
# python3 for the venv; what the wheels link to but do not carry (see the Containerfile)
DEBIAN_PACKAGES = ("python3", "python3-venv", "ca-certificates", "libglib2.0-0", "libstdc++6", "zlib1g")
LEFT_OUT = ("opencv_python-", "opencv_python_headless-")
#: declared by djitellopy, imported by neither it nor antalate (22 MB), but matplotlib's: kept for ``plot``
LEFT_OUT_UNLESS = {"pillow-": "plot"}
# glibc tags a bookworm (glibc 2.36) system accepts, newest first
_GLIBC = ("2_36", "2_35", "2_34", "2_31", "2_28", "2_27", "2_24", "2_17", "2_12", "2_5")
MACHINE = {"amd64": "x86_64", "arm64": "aarch64"}
# mmdebstrap's merged-/usr set-up (symlinks + usr-is-merged): without it, bookworm's essential
# init-system-helpers is satisfied by usrmerge, which pulls in the whole of perl (50 MB)
MERGED_USR_HOOK = Path("/usr/share/mmdebstrap/hooks/merged-usr")


class BuildError(RuntimeError):
    """A step failed: the message names it and ends with what the tool said."""


def host_arch() -> str:
    return {"x86_64": "amd64", "aarch64": "arm64"}.get(platform.machine(), platform.machine())


def run(
    cmd: Sequence[str], what: str, timeout: float = 1800, **kw: object
) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout, **kw)  # type: ignore[call-overload]
    if proc.returncode != 0:
        tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-40:])
        raise BuildError(f"{what} failed (exit {proc.returncode}): {' '.join(cmd)}\n{tail}")
    return proc


def build_wheel(out: Path) -> Path:
    run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(REPO)],
        "building antalate's wheel",
    )
    return sorted(out.glob("antalate-*.whl"))[-1]


def left_out(extras: Sequence[str] = ()) -> tuple[str, ...]:
    """Wheel-name prefixes dropped from the wheelhouse for these extras."""
    return LEFT_OUT + tuple(prefix for prefix, extra in LEFT_OUT_UNLESS.items() if extra not in extras)


def requirement(wheel: Path, extras: Sequence[str] = ()) -> str:
    """What pip is asked for: the wheel file, with its extras (``antalate-0.1.0-py3-none-any.whl[tello]``)."""
    return f"{wheel}[{','.join(extras)}]" if extras else str(wheel)


def wheelhouse(wheel: Path, out: Path, arch: str, extras: Sequence[str] = ()) -> list[Path]:
    """antalate's wheel and its (and ``extras``') dependencies' for ``arch`` in ``out`` (less `left_out`)."""
    out.mkdir(parents=True, exist_ok=True)
    shutil.copy2(wheel, out / wheel.name)
    machine = MACHINE[arch]
    platforms = [f"manylinux_{g}_{machine}" for g in _GLIBC] + [
        f"manylinux2014_{machine}",
        f"linux_{machine}",
    ]
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "-q",
        "--dest",
        str(out),
        "--only-binary=:all:",
        "--python-version",
        PYTHON_VERSION,
        "--implementation",
        "cp",
        *[a for p in platforms for a in ("--platform", p)],
        requirement(out / wheel.name, extras),
    ]
    run(cmd, f"downloading the dependencies' wheels for {arch}")
    for unused in (p for p in out.glob("*.whl") if p.name.startswith(left_out(extras))):
        unused.unlink()
    return sorted(out.glob("*.whl"))


def podman(opts: Sequence[str], *args: str) -> list[str]:
    return ["podman", *opts, *args]


def debian_rootfs(work: Path, arch: str) -> Path:
    """Debian bookworm as a tarball (mmdebstrap from Debian's mirror)."""
    tarball = work / f"base-{arch}.tar"
    cmd = [
        "mmdebstrap",
        "--variant=essential",
        f"--architectures={arch}",
        f"--include={','.join(DEBIAN_PACKAGES)}",
        "--dpkgopt=path-exclude=/usr/share/doc/*",
        "--dpkgopt=path-include=/usr/share/doc/*/copyright",
        "--dpkgopt=path-exclude=/usr/share/man/*",
        "--dpkgopt=path-exclude=/usr/share/locale/*",
        "--dpkgopt=path-exclude=/usr/share/info/*",
    ]
    if MERGED_USR_HOOK.is_dir():
        cmd.append(f"--hook-dir={MERGED_USR_HOOK}")
    for option in ("Acquire::Check-Valid-Until", "Acquire::Check-Date"):
        # what this host's apt was told about the mirror's dates (a snapshot mirror, a clock off)
        said = subprocess.run(["apt-config", "dump", option], capture_output=True, text=True).stdout
        if f'{option} "false";' in said:
            cmd.append(f'--aptopt={option} "false"')
    cmd += [DEBIAN_SUITE, str(tarball)]  # Debian's mirror, with bookworm-updates and security
    run(cmd, f"mmdebstrap of Debian {DEBIAN_SUITE} ({arch})")
    return tarball


def import_base(tarball: Path, arch: str, opts: Sequence[str], tag: str | None = None) -> str:
    """``podman import`` the root file system; returns the base image's reference."""
    tag = tag or f"localhost/antalate-base:{DEBIAN_SUITE}-{arch}"
    # an imported file system has no image config: give it the PATH every Debian image has
    change = ["--change", "ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"]
    run(
        podman(
            opts, "import", *change, *(["--arch", arch] if arch != host_arch() else []), str(tarball), tag
        ),
        "podman import of the base",
    )
    return tag


def build_image(
    context: Path, base: str, tag: str, arch: str, opts: Sequence[str], extras: Sequence[str] = ()
) -> None:
    shutil.copy2(HERE / "Containerfile", context / "Containerfile")
    shutil.copy2(HERE / "healthcheck.py", context / "healthcheck.py")
    pull = (
        "never" if base.startswith("localhost/") else "missing"
    )  # only a stock base may come from a registry
    run(
        podman(
            opts,
            "build",
            "--format",
            "docker",
            f"--pull={pull}",
            "--isolation",
            "chroot",
            "--network",
            "host",
            "--arch",
            arch,
            "--build-arg",
            f"BASE={base}",
            "--build-arg",
            f"EXTRAS={','.join(extras)}",
            "-t",
            tag,
            "-f",
            str(context / "Containerfile"),
            str(context),
        ),
        f"podman build of {tag}",
    )


def image_size(tag: str, opts: Sequence[str]) -> int:
    out = run(podman(opts, "image", "inspect", tag), "podman image inspect").stdout
    return int(json.loads(out)[0]["Size"])


def build(
    *,
    arch: str,
    tag: str,
    base: str | None,
    wheel: Path | None,
    opts: Sequence[str],
    work: Path,
    extras: Sequence[str] = (),
) -> tuple[str, int]:
    """Every step; returns the image's reference and size in bytes."""
    context = work / "context"
    wheels = context / "wheels"
    wheelhouse(wheel or build_wheel(work / "dist"), wheels, arch, extras)
    base_ref = base or import_base(debian_rootfs(work, arch), arch, opts)
    build_image(context, base_ref, tag, arch, opts, extras)
    return tag, image_size(tag, opts)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--arch", default=host_arch(), choices=sorted(MACHINE), help="target architecture")
    parser.add_argument("--tag", help="image reference (default localhost/antalate:VERSION[-EXTRA...]-ARCH)")
    parser.add_argument(
        "--extras",
        default="",
        help="antalate extras to install, comma-separated (e.g. tello; "
        "default none: the MAVLink and sim adapters)",
    )
    parser.add_argument("--base", help="base image reference (default: Debian made here by mmdebstrap)")
    parser.add_argument(
        "--wheel", type=Path, help="antalate wheel to install (default: built from this checkout)"
    )
    parser.add_argument("--podman-opt", action="append", default=[], help="global podman option (repeatable)")
    args = parser.parse_args(argv)
    for tool in ("podman", *(() if args.base else ("mmdebstrap",))):
        if shutil.which(tool) is None:
            print(f"build_image: {tool} is not installed (Debian: apt-get install {tool})", file=sys.stderr)
            return 2
    import tomllib

    version = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    extras = [e.strip() for e in args.extras.split(",") if e.strip()]
    tag = args.tag or f"localhost/antalate:{'-'.join([version, *extras, args.arch])}"
    with tempfile.TemporaryDirectory(prefix="antalate-image-") as tmp:
        try:
            ref, size = build(
                arch=args.arch,
                tag=tag,
                base=args.base,
                wheel=args.wheel,
                opts=args.podman_opt,
                work=Path(tmp),
                extras=extras,
            )
        except BuildError as exc:
            print(f"build_image: {exc}", file=sys.stderr)
            return 1
    print(f"built {ref}: {size / 1e6:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
