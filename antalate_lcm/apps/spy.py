"""``antalate spy``: start the stock ``lcm-spy`` with every antalate type on its classpath.

lcm-spy decodes a channel only if it finds a Java class whose ``LCM_FINGERPRINT`` matches, so we
generate the Java classes with ``lcm-gen``, compile them against the ``lcm.jar`` that ships in the
lcm wheel, and cache the jar until ``lcmtypes/`` changes.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sysconfig
import tempfile
import zipfile
from pathlib import Path

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.tools import codegen
from antalate_lcm.transports import transport_for

JDK_HINT = "install a JDK (Debian/Ubuntu: sudo apt-get install default-jdk-headless)"


def lcm_jar() -> Path:
    """The lcm.jar shipped inside the lcm Python wheel."""
    for base in {Path(sysconfig.get_path("purelib")), Path(sysconfig.get_path("platlib"))}:
        jar = base / "share" / "java" / "lcm.jar"
        if jar.exists():
            return jar
    raise AntalateError("lcm.jar not found: the 'lcm' wheel should ship it under site-packages/share/java")


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "antalate" / "java"


def types_digest() -> str:
    h = hashlib.sha256()
    for path in codegen.lcm_files():
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def build_types_jar(cache: Path | None = None) -> Path:
    """Compile every antalate LCM type to a jar (cached by the hash of ``lcmtypes/``) and return it."""
    javac = shutil.which("javac")
    if javac is None or shutil.which("java") is None:
        raise AntalateError(f"antalate spy needs Java: {JDK_HINT}")
    cache = cache or cache_dir()
    jar = cache / f"antalate_types-{types_digest()}.jar"
    if jar.exists():
        return jar
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        src, classes = Path(tmp) / "src", Path(tmp) / "classes"
        codegen.generate_java(src)
        sources = [str(p) for p in src.rglob("*.java")]
        classes.mkdir()
        proc = subprocess.run(
            [javac, "-nowarn", "-cp", str(lcm_jar()), "-d", str(classes), *sources],
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            raise AntalateError(f"javac failed on the generated types:\n{proc.stderr}")
        partial = jar.with_suffix(".tmp")
        with zipfile.ZipFile(partial, "w") as zf:
            for cls in classes.rglob("*.class"):
                zf.write(cls, cls.relative_to(classes).as_posix())
        partial.replace(jar)
    return jar


def spy_command(url: str, types_jar: Path) -> tuple[list[str], dict[str, str]]:
    env = dict(os.environ)
    env["CLASSPATH"] = os.pathsep.join(p for p in (str(types_jar), env.get("CLASSPATH", "")) if p)
    return [codegen.lcm_tool("lcm-spy"), f"--lcm-url={url}"], env


def run_spy(url: str) -> int:
    jar = build_types_jar()
    cmd, env = spy_command(url, jar)
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        raise AntalateError(
            "lcm-spy is a desktop program and no display is set: run it on a desktop, or headless with "
            f"xvfb-run -a (Debian/Ubuntu: sudo apt-get install xvfb). Types jar: {jar}"
        )
    return subprocess.call(cmd, env=env)


def spy_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="config file (default: the embedded defaults)")
    p.add_argument("--bus", help="bus name from the config (default: the default bus)")


def cmd_spy(args: argparse.Namespace) -> int:
    from antalate_lcm.core.config import load_config

    config = load_config(args.config)
    url = config.bus_url(args.bus or config.topics.default_bus)
    transport = transport_for(url)
    if transport.not_lcm:
        raise AntalateError(f"cannot spy on {url}: {transport.not_lcm}")
    return run_spy(url)
