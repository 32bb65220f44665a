"""The image, built once per session (a minute or two: mmdebstrap, the wheelhouse, podman build).

``built_image`` needs only what building needs (root, podman, mmdebstrap, a Debian mirror) and
skips with the reason where one is missing; ``antalate_image`` also needs a container to start
(``podman run``) and skips with podman's reason where none can (crun denied setrlimit, cgroups).
Once the base is imported, a failing image build is a failure.
"""

from __future__ import annotations

import os
import resource
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.containers.support import Podman, load_build_module, podman_unavailable
from tests.harness.netns import NetNamespace
from tests.harness.wheel_support import build_wheel


@dataclass
class Image:
    podman: Podman
    tag: str
    size: int
    build_seconds: float
    wheel: Path
    work: Path
    #: why no container can start here (None: podman run works, with ``podman.run_flags``)
    cannot_run: str | None = None


@pytest.fixture(scope="session")
def built_image(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Image]:
    reason = podman_unavailable()
    if reason:
        pytest.skip(reason)
    build = load_build_module()
    arch = build.host_arch()
    work = tmp_path_factory.mktemp("image")
    started = time.monotonic()
    wheel = build_wheel(work)
    try:
        rootfs = build.debian_rootfs(work, arch)
    except build.BuildError as exc:
        pytest.skip(f"cannot make the Debian base here (mmdebstrap): {exc}")
    problems = []
    chosen: Podman | None = None
    imported: Podman | None = None  # the first storage the base went into: enough to build
    base = ""
    # every container of the session runs on the host network of a private namespace: never the host's
    netns = NetNamespace(root=True).start()
    # podman's own folders on a short path: conmon's sockets live there (sun_path is 108 bytes)
    podman_root = Path(tempfile.mkdtemp(prefix="antalate-ct-", dir="/var/tmp"))
    for driver in ("overlay", "vfs"):  # vfs where overlay cannot be mounted (nested containers)
        pod = Podman(podman_root / driver, driver, netns)
        try:
            base = build.import_base(rootfs, arch, pod.opts)
        except build.BuildError as exc:
            problems.append(f"{driver}: {exc}")
            continue
        # podman 4.3 schedules health checks with systemd timers, which a host without systemd lacks
        # (an error in its log): the tests run the image's check by hand (podman exec) instead
        common = ["--log-driver=k8s-file", "--no-healthcheck"]
        for flags in (common, [*common, "--cgroups=disabled"], [*common, *_sandbox_ulimits()]):
            probe = pod("run", "--rm", "--network", "host", *flags, base, "/bin/true", timeout=120)
            if probe.returncode == 0:
                pod.run_flags = flags
                chosen = pod
                break
            problems.append(f"{driver} {' '.join(flags)}: {probe.stderr.strip()[-500:]}")
            if _HYBRID in probe.stderr and _free_cgroup2_of_hugetlb():
                probe = pod("run", "--rm", "--network", "host", *flags, base, "/bin/true", timeout=120)
                if probe.returncode == 0:
                    pod.run_flags = flags
                    chosen = pod
                    break
                problems.append(
                    f"{driver} {' '.join(flags)} (hugetlb moved to cgroup v1): {probe.stderr.strip()[-500:]}"
                )
        if chosen is not None:
            break
        if imported is None:
            imported = pod
        else:
            pod.reset()
    builder = chosen or imported
    if builder is None:
        netns.close()
        shutil.rmtree(podman_root, ignore_errors=True)
        pytest.skip("podman cannot import the base here:\n" + "\n".join(problems))
    if chosen is not None and imported is not None and imported is not chosen:
        imported.reset()
    cannot_run = None if chosen is not None else "podman cannot run a container here:\n" + "\n".join(problems)
    tag = f"localhost/antalate:test-{arch}"
    context = work / "context"
    try:
        build.wheelhouse(wheel, context / "wheels", arch)
        build.build_image(context, base, tag, arch, builder.opts)  # a failure here is the image's fault
    except BaseException:
        builder.reset()
        netns.close()
        shutil.rmtree(podman_root, ignore_errors=True)
        raise
    size = build.image_size(tag, builder.opts)
    image = Image(builder, tag, size, time.monotonic() - started, wheel, work, cannot_run)
    print(
        f"\nantalate image {tag}: {size / 1e6:.0f} MB, built in {image.build_seconds:.0f} s "
        f"(storage {builder.driver}, run flags {builder.run_flags or 'none'}"
        f"{'' if cannot_run is None else ', containers cannot start here'})"
    )
    try:
        yield image
    finally:
        builder.reset()
        netns.close()
        shutil.rmtree(podman_root, ignore_errors=True)


_HYBRID = "cgroups in hybrid mode not supported"


def _sandbox_ulimits() -> list[str]:
    """Limits a sandboxed root may set: podman asks for more open files and processes than some VMs'
    hard limits (crun's setrlimit then fails with EPERM), so ask for the hard limit of open files
    and a modest process count instead."""
    nofile = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    nofile = nofile if nofile != resource.RLIM_INFINITY else 1 << 20
    return [f"--ulimit=nofile={nofile}:{nofile}", "--ulimit=nproc=4096:4096"]


def _free_cgroup2_of_hugetlb() -> bool:
    """crun refuses a hybrid cgroup host whose v2 hierarchy still holds a controller (hugetlb in some
    CI VMs). Mounting that controller on a v1 hierarchy of its own empties v2. This changes the
    host, so it is done only on CI (``CI=true``, a throw-away machine) or when asked for with
    ``ANTALATE_TEST_FIX_CGROUPS=1``, and only as root."""
    if os.geteuid() != 0 or not (
        os.environ.get("CI") == "true" or os.environ.get("ANTALATE_TEST_FIX_CGROUPS") == "1"
    ):
        return False
    unified = Path("/sys/fs/cgroup/unified/cgroup.controllers")
    try:
        controllers = unified.read_text().split()
    except OSError:
        return False
    for controller in controllers:
        target = Path("/sys/fs/cgroup") / controller
        target.mkdir(exist_ok=True)
        done = subprocess.run(
            ["mount", "-t", "cgroup", "-o", controller, "cgroup", str(target)], capture_output=True, text=True
        )
        if done.returncode != 0:
            return False
    return True


@pytest.fixture(scope="session")
def antalate_image(built_image: Image) -> Image:
    """The built image, where a container can start from it."""
    if built_image.cannot_run:
        pytest.skip(built_image.cannot_run)
    return built_image
