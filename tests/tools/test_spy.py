"""Cross-language checks: the lcm-gen Java classes decode what Python encodes, and ``lcm-spy`` finds them.

The Java side is ``tests/java/DecodeCheck.java``, compiled here against ``lcm.jar`` and the types jar
that ``antalate spy`` builds. lcm-spy itself runs headless under ``xvfb-run`` inside a private network
namespace, so its multicast socket never touches the host's network.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import math
import os
import shutil
import signal
import struct
import subprocess
import sys
import time
import uuid
import zipfile
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.apps import spy
from antalate_lcm.msgs import header_t, mc_state_t, telemetry_t
from antalate_lcm.tools import codegen as _codegen
from antalate_lcm.wire.topics import Message
from tests import REPO
from tests.harness.lcm_tables import dimensions, fingerprint, slots, typenames
from tests.harness.netns import private_netns, require_netns
from tests.harness.polling import wait_for
from tests.harness.process import OutputLines, group_members, stop_process

JAVA_SRC = Path(__file__).resolve().parent.parent / "java" / "DecodeCheck.java"
MCAST_URL = "udpm://239.255.76.67:7667?ttl=0"
TYPE_NAMES = [p.stem for p in _codegen.lcm_files()]

needs_java = pytest.mark.skipif(
    shutil.which("java") is None or shutil.which("javac") is None,
    reason=f"java/javac not found: {spy.JDK_HINT}",
)


def msg_class(type_name: str) -> type[Message]:
    """The generated Python class for an LCM type name, short (``telemetry_t``) or qualified."""
    short = type_name.rsplit(".", 1)[-1]
    cls: type[Message] = getattr(importlib.import_module(f"antalate_lcm.msgs.{short}"), short)
    return cls


def f32(x: float) -> float:
    """What a Python float becomes once it travels as an LCM ``float``."""
    single: float = struct.unpack(">f", struct.pack(">f", x))[0]
    return single


# -- messages with known values --------------------------------------------------------------------


def known_telemetry() -> telemetry_t:
    msg = telemetry_t()
    msg.header = header(1_763_836_800_123_456, "alpha", 4242)
    msg.lat, msg.lon = 32.776664, 35.023056
    msg.alt, msg.heading = 12.5, 271.3
    msg.vn, msg.ve, msg.vd = 1.25, -0.1, 0.0
    msg.battery = 87.6
    msg.armed, msg.in_air = True, False
    msg.mode = "GUIDED"
    return msg


def known_mc_state() -> mc_state_t:
    msg = mc_state_t()
    msg.header = header(-1, "swarm-7", -2)
    msg.header.mac_len, msg.header.mac = 4, bytes([0x00, 0x7F, 0x80, 0xFF])  # a MAC's bytes, signed in Java
    msg.state = mc_state_t.MISSION
    msg.last_command_seq = 2_147_483_647
    msg.takeoff_altitude = 12.5
    msg.reason = "vehicle failsafe: fence breach"
    return msg


def header(utime: int, agent: str, seq: int) -> header_t:
    h = header_t()
    h.utime, h.agent, h.seq = utime, agent, seq
    return h


def sample(msg_type: type, salt: int = 1) -> Any:
    """A message of any generated type with distinct non-default values in every field.

    Driven by the generated class's own field tables, so a field added to a ``.lcm`` file is covered
    without touching this test. Variable-length arrays get three elements and their length field set.
    """
    msg = msg_type()
    for k, (name, tname, dims) in enumerate(
        zip(slots(msg_type), typenames(msg_type), dimensions(msg_type), strict=True)
    ):
        s = salt * 31 + k
        if dims is None:
            setattr(msg, name, scalar(tname, s))
            continue
        assert len(dims) == 1, f"{msg_type.__name__}.{name}: multi-dimensional arrays are not covered"
        n = dims[0] if isinstance(dims[0], int) else 3
        if tname == "byte":
            value: Any = bytes((s * 7 + i) % 256 for i in range(n))
        else:
            value = [scalar(tname, s + i) for i in range(n)]
        setattr(msg, name, value)
        if not isinstance(dims[0], int):
            setattr(msg, dims[0], n)
    return msg


def scalar(tname: str, s: int) -> Any:
    values: dict[str, Any] = {
        "int8_t": -(s % 120) - 1,
        "int16_t": -1000 - s,
        "int32_t": 100_000 + s,
        "int64_t": 1_763_836_800_000_000 + s,
        "float": s + 0.1,  # not exact in float32: checks the rounding matches
        "double": s / 7,
        "boolean": s % 2 == 0,
        "string": f"s{s}-ok",
        "byte": s % 256,
    }
    if tname in values:
        return values[tname]
    return sample(msg_class(tname), s)


# -- comparing Python's view with Java's -----------------------------------------------------------


def assert_same(py: Any, java: Any, msg_type: type, path: str) -> None:
    """``py`` is the Python-decoded message, ``java`` the JSON DecodeCheck printed for it."""
    assert isinstance(java, dict), f"{path}: Java gave {java!r}"
    assert set(java) == set(slots(msg_type)), f"{path}: Java fields {sorted(java)}"
    for name, tname, dims in zip(slots(msg_type), typenames(msg_type), dimensions(msg_type), strict=True):
        pv, jv = getattr(py, name), java[name]
        where = f"{path}.{name}"
        if dims is not None and tname == "byte":
            assert jv == bytes(pv).hex(), where
        elif dims is not None:
            assert isinstance(jv, list) and len(jv) == len(pv), f"{where}: {jv!r} vs {pv!r}"
            for i, (p, j) in enumerate(zip(pv, jv, strict=True)):
                assert_scalar(p, j, tname, f"{where}[{i}]")
        else:
            assert_scalar(pv, jv, tname, where)


def assert_scalar(pv: Any, jv: Any, tname: str, where: str) -> None:
    if tname == "float":
        # Java prints the shortest decimal that identifies the float32; round it back to compare bit-exactly.
        assert f32(jv) == pv or (math.isnan(jv) and math.isnan(pv)), f"{where}: Java {jv!r}, Python {pv!r}"
    elif tname == "double":
        assert jv == pv, f"{where}: Java {jv!r}, Python {pv!r}"
    elif "." in tname:  # a nested struct, e.g. antalate_lcm.msgs.header_t
        assert_same(pv, jv, msg_class(tname), where)
    else:
        assert jv == pv and type(jv) is type(pv), f"{where}: Java {jv!r}, Python {pv!r}"


# -- fixtures --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def types_jar(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("java") is None or shutil.which("javac") is None:
        pytest.skip(f"java/javac not found: {spy.JDK_HINT}")
    return spy.build_types_jar(cache=tmp_path_factory.mktemp("jar-cache"))


@pytest.fixture(scope="module")
def java_cp(types_jar: Path, tmp_path_factory: pytest.TempPathFactory) -> str:
    """Classpath with lcm.jar, the antalate types and the compiled DecodeCheck."""
    classes = tmp_path_factory.mktemp("decodecheck")
    cp = os.pathsep.join([str(spy.lcm_jar()), str(types_jar)])
    proc = subprocess.run(
        ["javac", "-nowarn", "-cp", cp, "-d", str(classes), str(JAVA_SRC)], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    return os.pathsep.join([cp, str(classes)])


def run_java(cp: str, *args: str) -> list[str]:
    env = {k: v for k, v in os.environ.items() if k != "CLASSPATH"}
    proc = subprocess.run(
        ["java", "-cp", cp, "DecodeCheck", *args], capture_output=True, text=True, env=env, timeout=60
    )
    assert proc.returncode == 0, f"DecodeCheck failed:\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout.splitlines()


# -- tests -----------------------------------------------------------------------------------------


@needs_java
def test_java_decodes_what_python_encodes(java_cp: str, tmp_path: Path) -> None:
    messages: dict[str, Any] = {name: sample(msg_class(name), i + 1) for i, name in enumerate(TYPE_NAMES)}
    messages["telemetry_t"] = known_telemetry()
    messages["mc_state_t"] = known_mc_state()
    encoded = {name: msg.encode() for name, msg in messages.items()}
    for name, data in encoded.items():
        (tmp_path / f"{name}.bin").write_bytes(data)

    lines = run_java(java_cp, "decode", str(tmp_path), *messages)
    decoded = {d["type"]: d["fields"] for d in map(json.loads, lines)}
    assert set(decoded) == set(messages)

    # the two messages spelled out, as a reader of lcm-spy would see them
    tel = decoded["telemetry_t"]
    assert tel["header"] == {
        "utime": 1_763_836_800_123_456,
        "agent": "alpha",
        "seq": 4242,
        "mac_len": 0,
        "mac": "",
    }
    assert (tel["lat"], tel["lon"]) == (32.776664, 35.023056)
    assert (tel["alt"], tel["heading"], tel["vn"], tel["ve"], tel["vd"], tel["battery"]) == (
        12.5, 271.3, 1.25, -0.1, 0.0, 87.6,
    )  # fmt: skip
    assert (tel["armed"], tel["in_air"], tel["mode"]) == (True, False, "GUIDED")
    mc = decoded["mc_state_t"]
    assert mc == {
        "header": {"utime": -1, "agent": "swarm-7", "seq": -2, "mac_len": 4, "mac": "007f80ff"},
        "state": 3,
        "last_command_seq": 2_147_483_647,
        "takeoff_altitude": 12.5,
        "reason": "vehicle failsafe: fence breach",
    }
    assert mc["state"] == mc_state_t.MISSION

    # every type, field by field, against the Python decoder; and Java's re-encoding is byte-identical
    for name, data in encoded.items():
        cls = msg_class(name)
        assert_same(cls.decode(data), decoded[name], cls, name)
        assert (tmp_path / f"{name}.java.bin").read_bytes() == data, f"{name}: Java re-encodes differently"


@needs_java
def test_lcm_spy_type_database_maps_every_fingerprint(java_cp: str) -> None:
    """lcm-spy's own classpath scan (LCMTypeDatabase) maps each Python fingerprint to the right class."""
    args = [f"{name}={fingerprint(msg_class(name)).hex()}" for name in TYPE_NAMES]
    lines = run_java(java_cp, "spytypes", *args)
    found = dict(line.split("=", 1) for line in lines if "=" in line and not line.startswith(" "))
    assert found == {name: f"antalate_lcm.msgs.{name}" for name in TYPE_NAMES}
    assert f"Found {len(TYPE_NAMES)} LCM types" in lines


@needs_java
@pytest.mark.netns
def test_lcm_spy_headless_finds_every_antalate_type(types_jar: Path, tmp_path: Path) -> None:
    if shutil.which("xvfb-run") is None:
        pytest.skip("xvfb-run not found (Debian/Ubuntu: apt-get install xvfb xauth)")
    if shutil.which("xauth") is None:
        pytest.skip("xauth not found, which xvfb-run needs (Debian/Ubuntu: apt-get install xauth)")
    require_spy_window()
    cmd, env = spy.spy_command(MCAST_URL, types_jar)
    marker = f"-Dantalate.test={uuid.uuid4().hex}"  # finds our JVM in /proc if it outlives the test
    env["LCM_JVM_OPT"] = f"-Xmx128m -Xms64m {marker}"
    env.pop("DISPLAY", None)
    env["TMPDIR"] = str(tmp_path)  # xvfb-run's Xauthority folder: checked below that it is cleaned up
    out, pgid = spy_window(cmd, marker, 45, env=env)
    text = "\n".join(out)
    counts = [
        int(line.split()[1]) for line in out if line.startswith("Found ") and line.endswith(" LCM types")
    ]
    assert counts, f"lcm-spy did not report its types:\n{text}"
    # lcm-spy counts distinct fingerprints on its classpath: ours, plus any lcm may ship some day
    assert counts[0] >= len(TYPE_NAMES), text
    assert "Exception in thread" not in text and "Couldn't create LCM" not in text, text
    assert wait_for(lambda: not group_members(pgid), 5), f"outlived stop_process: {group_members(pgid)}"
    assert wait_for(lambda: not _marked_processes(marker), 5), "lcm-spy's JVM outlived the test"
    assert not list(tmp_path.glob("xvfb-run.*")), "xvfb-run did not clean up: it was killed, not stopped"


def _jdk_is_headless() -> bool:
    """Debian's *-jre-headless packages lack the X11 toolkit; lcm-spy then dies opening its window."""
    java = shutil.which("java")
    if java is None:
        return True
    home = Path(os.path.realpath(java)).parent.parent
    libs = list(home.glob("lib/libawt_xawt.*")) + list(home.glob("lib/*/libawt_xawt.*"))
    return sys.platform.startswith("linux") and not libs


def require_spy_window() -> None:
    """Skip, saying why, where lcm-spy's window cannot open in a private namespace."""
    if _jdk_is_headless():
        pytest.skip(
            "this Java has no AWT for X11 (libawt_xawt.so), which lcm-spy's window needs (Debian: default-jre)"
        )
    require_netns()


def spy_window(cmd: list[str], marker: str, timeout: float, **kw: Any) -> tuple[list[str], int]:
    """lcm-spy (``cmd``, its JVM marked with ``marker``) under xvfb-run in a private namespace, until it
    reports its plugins, then stopped: its output lines and its process group.

    "Found N plugins" is printed after the window is shown and LCM has joined the group. The stop is
    clean: the JVM ends, so xvfb-run stops Xvfb and removes its files itself; stop_process then ends
    whatever is left of the process group."""
    with private_netns() as ns:
        proc = ns.popen(
            ["xvfb-run", "-a", "-s", "-screen 0 1024x768x24", *cmd],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            **kw,
        )
        assert proc.stdout is not None
        out = OutputLines(proc.stdout)
        try:
            if (
                out.wait(lambda line: line.startswith("Found ") and line.endswith(" plugins"), timeout)
                is None
            ):
                pytest.fail(f"lcm-spy did not start (exit code {proc.poll()}):\n{out.text()}")
            time.sleep(0.5)
            assert proc.poll() is None, "lcm-spy exited:\n" + out.text()
        finally:
            for pid in _marked_processes(marker):
                os.kill(pid, signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(10)
            stop_process(proc)
    out.join()
    return out.lines, proc.pid


def _marked_processes(marker: str) -> list[int]:
    hits = []
    for pid in _pids():
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if marker.encode() in cmdline and _state(pid) != "Z":
            hits.append(pid)
    return hits


def _pids() -> list[int]:
    return [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit()]


def _state(pid: int) -> str | None:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[1].split()[0]


def test_cli_spy_without_display_says_how(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["XDG_CACHE_HOME"] = str(tmp_path)  # never the developer's own jar cache
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    proc = subprocess.run(
        [sys.executable, "-m", "antalate_lcm.cli", "spy"], capture_output=True, text=True, env=env, timeout=60
    )
    assert proc.returncode == 2, proc.stderr
    if shutil.which("java") and shutil.which("javac"):
        assert "xvfb-run" in proc.stderr and "no display" in proc.stderr, proc.stderr
    else:  # without a JDK the jar cannot be built, and that is said first
        assert "install a JDK" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


@needs_java
def test_types_jar_is_cached_and_rebuilt_when_types_change(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    jar = spy.build_types_jar(cache=tmp_path)
    assert jar.parent == tmp_path and spy.types_digest() in jar.name
    with zipfile.ZipFile(jar) as zf:
        names = sorted(zf.namelist())
    assert names == sorted(f"antalate_lcm/msgs/{n}.class" for n in TYPE_NAMES)
    mtime = jar.stat().st_mtime_ns

    def no_codegen(out_dir: Path) -> Path:
        raise AssertionError("the cached jar should have been reused")

    with monkeypatch.context() as m:
        m.setattr(_codegen, "generate_java", no_codegen)
        assert spy.build_types_jar(cache=tmp_path) == jar
    assert jar.stat().st_mtime_ns == mtime

    monkeypatch.setattr(spy, "types_digest", lambda: "0123456789abcdef")
    rebuilt = spy.build_types_jar(cache=tmp_path)
    assert rebuilt != jar and rebuilt.name == "antalate_types-0123456789abcdef.jar"
    with zipfile.ZipFile(rebuilt) as zf:
        assert sorted(zf.namelist()) == names
    assert not list(tmp_path.glob("*.tmp")), "a partial jar was left behind"


def test_types_digest_follows_lcmtypes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Editing a .lcm file changes the digest, so the cached jar is never stale."""
    for src in _codegen.lcm_files():
        shutil.copy(src, tmp_path / src.name)
    monkeypatch.setattr(_codegen, "LCMTYPES_DIR", tmp_path)
    before = spy.types_digest()
    target = tmp_path / "telemetry_t.lcm"
    target.write_text(target.read_text() + "\n// edited\n")
    assert spy.types_digest() != before
