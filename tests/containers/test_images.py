"""The container image: one image, every node kind in its own container, a mission flown.

MC, HLC, BMA, OSC and the station each run in a container of the same image (config mounted
read-only, host networking, uid 10001); the LAN test operator (tests/lan/lan_operator.py, the
console's own command tracking) runs outside them in the same private network namespace, signs
with the swarm key and flies TAKEOFF, MISSION, RTL. Each container's health check passes while its
node works. About 3 minutes with the image build (once per session), 40 s without. Where no
container can start (crun denied its rlimits, cgroups), the image's file system is still checked:
mounted (``podman image mount``) and entered with chroot as the image's user and ENV.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
import tomli_w

from tests import REPO
from tests.containers.conftest import Image
from tests.containers.support import Podman, load_build_module
from tests.harness.agents import agent_config
from tests.harness.netns import NetNamespace
from tests.lan.swarm import OperatorClient

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

MCAST = "udpm://239.255.76.67:7667?ttl=0"
KEY = "container-test-swarm-key"
HEALTHCHECK = ["/opt/antalate/bin/python", "/usr/local/lib/antalate-healthcheck.py"]
# the module every node kind runs, the LCM binding and the MAVLink adapter (the default image's vehicle)
NODE_IMPORTS = (
    "import lcm, antalate_lcm.cli, antalate_lcm.agent.mc, antalate_lcm.agent.hlc.node, antalate_lcm.agent.bma, "
    "antalate_lcm.agent.osc, antalate_lcm.station, antalate_lcm.vehicles.mavlink, "
    "antalate_lcm.vehicles.tello, operator_tui.web; from pymavlink import mavutil"
)
# what the default image leaves out: opencv (never imported), the tello and plot extras
LEFT_OUT_CHECK = (
    "import importlib.util as u, sys; "
    "bad = [m for m in ('cv2', 'djitellopy', 'av', 'numpy', 'matplotlib') if u.find_spec(m)]; "
    "sys.exit(f'in the image but left out: {bad}' if bad else 0)"
)
# antalate's source files in the venv, and those without compiled bytecode (prints "missing total")
STALE_BYTECODE = (
    "import importlib.util as u, pathlib, sys; "
    "fs = [f for f in pathlib.Path(sys.prefix, 'lib').rglob('*.py') if 'antalate_lcm' in f.parts]; "
    "print(sum(1 for f in fs if not pathlib.Path(u.cache_from_source(str(f))).exists()), len(fs))"
)


def test_image_is_one_non_root_image_with_its_health_check(antalate_image: Image) -> None:
    pod, tag = antalate_image.podman, antalate_image.tag
    print(f"image size: {antalate_image.size / 1e6:.0f} MB (target < 400 MB)")
    config = json.loads(pod("image", "inspect", tag).stdout)[0]
    text = json.dumps(config)
    assert "antalate-healthcheck.py" in text, "the HEALTHCHECK did not reach the image (OCI format?)"
    assert config["Config"]["User"] == "10001:10001"
    assert config["Config"]["Entrypoint"] == ["antalate"]
    who = pod("run", "--rm", "--network", "host", *pod.run_flags, "--entrypoint", "id", tag, "-u")
    assert who.returncode == 0 and who.stdout.strip() == "10001", who.stderr
    # every node kind is a subcommand of the one entry point; opencv was left out, pymavlink works
    helps = pod("run", "--rm", "--network", "host", *pod.run_flags, tag, "--help")
    assert helps.returncode == 0, helps.stderr
    listed = {
        line.split()[0] for line in helps.stdout.splitlines() if line.startswith("    ") and line.split()
    }
    assert {"mc", "hlc", "bma", "osc", "agent", "station", "tui", "types"} <= listed, helps.stdout
    probe = pod(
        "run",
        "--rm",
        "--network",
        "host",
        *pod.run_flags,
        "--entrypoint",
        "/opt/antalate/bin/python",
        tag,
        "-c",
        f"{NODE_IMPORTS}; {LEFT_OUT_CHECK}",
    )
    assert probe.returncode == 0, probe.stdout + probe.stderr
    assert antalate_image.size < 400e6, f"{antalate_image.size / 1e6:.0f} MB: something big came back"


def image_env(image: Image) -> list[str]:
    """The image's ENV (PATH, MAVLINK_DIALECT, HOME, XDG_*) as ``env -i`` arguments."""
    config = json.loads(image.podman("image", "inspect", image.tag).stdout)[0]
    return ["env", "-i", *config["Config"]["Env"]]


@pytest.fixture
def image_root(built_image: Image) -> Iterator[Path]:
    """The image's file system (``podman image mount``), for chroot where containers cannot start."""
    pod = built_image.podman
    mounted = pod("image", "mount", built_image.tag)
    if mounted.returncode != 0:
        pytest.skip(f"podman cannot mount the image here: {mounted.stderr.strip()}")
    try:
        yield Path(mounted.stdout.strip())
    finally:
        pod("image", "unmount", built_image.tag)


def test_every_node_kind_imports_in_the_image_as_its_user(built_image: Image, image_root: Path) -> None:
    """The image works even where no container can start: its own python, its ENV, uid 10001, chroot."""
    size = built_image.size
    print(f"image size: {size / 1e6:.0f} MB (target < 400 MB)")
    assert size < 400e6, f"{size / 1e6:.0f} MB: something big came back"
    chroot = ["chroot", "--userspec=10001:10001", str(image_root), *image_env(built_image)]

    def run(*argv: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*chroot, *argv], capture_output=True, text=True, timeout=120, cwd="/")

    helps = run("antalate", "--help")
    assert helps.returncode == 0, helps.stderr
    listed = {
        line.split()[0] for line in helps.stdout.splitlines() if line.startswith("    ") and line.split()
    }
    assert {"mc", "hlc", "bma", "osc", "agent", "station", "tui", "types"} <= listed, helps.stdout
    probe = run("/opt/antalate/bin/python", "-c", f"{NODE_IMPORTS}; {LEFT_OUT_CHECK}")
    assert probe.returncode == 0, probe.stdout + probe.stderr
    # what was left out says so in one line, as on any install without the extra
    plot = run("antalate", "plot", "/var/lib/antalate/flight.lcm")
    assert plot.returncode == 2 and plot.stderr.strip().endswith("pip install 'antalate[plot]'"), plot.stderr
    tello = run(
        "/opt/antalate/bin/python",
        "-c",
        "from antalate_lcm.vehicles.tello import TelloAdapter\n"
        "try:\n    TelloAdapter({'host': '127.0.0.1'}).connect()\n"
        "except Exception as exc:\n    print(exc)",
    )
    assert "pip install 'antalate[tello]'" in tello.stdout, tello.stdout + tello.stderr
    # bytecode is there and current: a node as uid 10001 (who cannot write /opt) does not compile at start
    stale = run("/opt/antalate/bin/python", "-c", STALE_BYTECODE)
    assert stale.returncode == 0, stale.stderr
    missing, total = map(int, stale.stdout.split())
    assert total > 50 and missing == 0, f"{missing} of {total} modules without bytecode"


@pytest.fixture
def netns() -> Iterator[NetNamespace]:
    ns = NetNamespace(root=True).start()
    try:
        yield ns
    finally:
        ns.close()


def test_a_mission_with_every_node_in_its_own_container(
    antalate_image: Image, netns: NetNamespace, tmp_path: Path
) -> None:
    pod = antalate_image.podman.in_netns(netns)
    tag = antalate_image.tag
    agent = agent_config(
        "alpha",
        security={"swarm_key": KEY},
        osc={"enabled": True, "server": "http://127.0.0.1:8080", "rate": 2.0},
        bma=[{"name": "swarm"}],
    )
    agent["buses"] = {"lan": MCAST}
    agent_toml = tmp_path / "alpha.toml"
    agent_toml.write_text(tomli_w.dumps(agent))
    operator_toml = tmp_path / "operator.toml"
    operator_toml.write_text(
        tomli_w.dumps(
            {
                "agent": {"name": "operator"},
                "buses": {"lan": MCAST},
                "topics": {"default_bus": "lan"},
                "security": {"swarm_key": KEY, "state_dir": str(tmp_path / "operator-state")},
            }
        )
    )
    for f in (agent_toml, operator_toml):
        f.chmod(0o644)
    run_id = uuid.uuid4().hex[:8]
    mount = ["-v", f"{agent_toml}:/etc/antalate/agent.toml:ro"]
    nodes = {
        "station": ["station", "--host", "127.0.0.1", "--port", "8080", "--db", ":memory:"],
        "mc": ["mc", "/etc/antalate/agent.toml"],
        "hlc": ["hlc", "/etc/antalate/agent.toml"],
        "bma": ["bma", "/etc/antalate/agent.toml", "--name", "swarm"],
        "osc": ["osc", "/etc/antalate/agent.toml"],
    }
    names = {node: f"antalate-{node}-{run_id}" for node in nodes}
    try:
        for node, args in nodes.items():
            # pod.run_flags has --no-healthcheck: the check is run by hand below (podman exec)
            started = pod(
                "run",
                "-d",
                "--name",
                names[node],
                "--network",
                "host",
                *pod.run_flags,
                *([] if node == "station" else mount),
                tag,
                *args,
            )
            assert started.returncode == 0, f"{node}: {started.stderr}"
        proc = netns.popen(
            [sys.executable, "-m", "tests.lan.lan_operator", str(operator_toml)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        op = OperatorClient(proc)
        try:
            op.wait_all(["alpha"], "STANDBY", timeout=90)
            op.command("TAKEOFF", altitude=3.0)
            op.wait_all(["alpha"], "MISSION", timeout=60)
            health = {node: pod("exec", names[node], *HEALTHCHECK, timeout=60) for node in nodes}
            for node, result in health.items():
                assert result.returncode == 0 and result.stdout.startswith("healthy"), (
                    f"{node}: {result.stdout}{result.stderr}\n{logs(pod, names[node])}"
                )
            op.command("RTL")
            op.wait_all(["alpha"], "STANDBY", timeout=90)
            status = op.wait(lambda s: s["pending"] == 0, timeout=20, what="no command pending")
            assert [c["status"] for c in status["commands"]] == ["acked", "acked"], status["commands"]
        finally:
            op.quit()
        assert wait_logged(pod, names["station"], "new agent 'alpha'"), logs(pod, names["station"])
        assert "registered with the station as 'alpha'" in logs(pod, names["osc"])
        for node in nodes:
            uid = pod("exec", names[node], "id", "-u")
            assert uid.stdout.strip() == "10001", f"{node} runs as {uid.stdout.strip()}"
            assert "Traceback" not in logs(pod, names[node]), logs(pod, names[node])
        # a node that stops is reported unhealthy by the others' image: the MC gone, the OSC's check fails
        pod("stop", "--time", "5", names["mc"])
        sick = pod("exec", names["osc"], *HEALTHCHECK, timeout=60)
        assert sick.returncode == 1 and "the MC_STATE it forwards not heard" in sick.stdout, (
            sick.stdout + sick.stderr
        )
    finally:
        for name in names.values():
            pod("stop", "--time", "5", name, timeout=120)
            pod("rm", "--force", name, timeout=120)


def logs(pod: Podman, name: str) -> str:
    out = pod("logs", name, timeout=60)
    return out.stdout + out.stderr


def wait_logged(pod: Podman, name: str, text: str, timeout: float = 20) -> bool:
    from tests.harness.polling import wait_for

    return bool(wait_for(lambda: text in logs(pod, name), timeout, interval=0.5))


def binfmt_arm64() -> str | None:
    """Why an arm64 image cannot be built here, or None."""
    if platform.machine() == "aarch64":
        return None
    handler = Path("/proc/sys/fs/binfmt_misc/qemu-aarch64")
    if not handler.exists():
        return (
            "this host has no binfmt_misc handler for arm64 (/proc/sys/fs/binfmt_misc/qemu-aarch64): install "
            "qemu-user-static and binfmt-support where the kernel allows binfmt_misc"
        )
    if "enabled" not in handler.read_text():
        return "the qemu-aarch64 binfmt_misc handler is disabled"
    return None


def test_the_same_image_builds_for_arm64(antalate_image: Image) -> None:
    reason = binfmt_arm64()
    if reason:
        pytest.skip(reason)
    build = load_build_module()
    pod = antalate_image.podman
    work = antalate_image.work / "arm64"
    work.mkdir()
    try:
        rootfs = build.debian_rootfs(work, "arm64")
    except build.BuildError as exc:
        pytest.skip(f"cannot make the arm64 Debian base here: {exc}")
    base = build.import_base(rootfs, "arm64", pod.opts)
    build.wheelhouse(antalate_image.wheel, work / "context" / "wheels", "arm64")
    tag = "localhost/antalate:test-arm64"
    build.build_image(work / "context", base, tag, "arm64", pod.opts)
    arch = pod(
        "run",
        "--rm",
        "--arch",
        "arm64",
        "--network",
        "host",
        *pod.run_flags,
        "--entrypoint",
        "uname",
        tag,
        "-m",
    )
    assert arch.stdout.strip() == "aarch64", arch.stderr
    helps = pod(
        "run", "--rm", "--arch", "arm64", "--network", "host", *pod.run_flags, tag, "--help", timeout=300
    )
    assert helps.returncode == 0 and "station" in helps.stdout, helps.stderr
    print(f"arm64 image: {build.image_size(tag, pod.opts) / 1e6:.0f} MB")


def test_build_script_refuses_without_its_tools(tmp_path: Path) -> None:
    """The user's entry point says what is missing instead of failing half-way (runs everywhere)."""
    env = dict(os.environ, PATH=str(tmp_path))  # no podman, no mmdebstrap
    proc = subprocess.run(
        [sys.executable, str(REPO / "containers" / "build_image.py")],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert proc.returncode == 2 and "podman is not installed" in proc.stderr, proc.stderr


def test_the_wheelhouse_asks_for_the_extras_and_drops_only_what_nothing_imports() -> None:
    """Runs everywhere: what pip is asked for per variant, and what is dropped from its answer."""
    build = load_build_module()
    wheel = Path("/w/antalate-0.1.0-py3-none-any.whl")
    assert build.requirement(wheel) == str(wheel)
    assert build.requirement(wheel, ["tello", "crazyflie"]) == f"{wheel}[tello,crazyflie]"
    default, tello, plot = build.left_out(()), build.left_out(("tello",)), build.left_out(("tello", "plot"))
    assert "opencv_python-" in default and "opencv_python-" in plot  # nothing imports cv2
    assert "pillow-" in default and "pillow-" in tello  # djitellopy declares it, nothing imports PIL ...
    assert "pillow-" not in plot  # ... but matplotlib does
    assert not any(p.startswith(("djitellopy", "av-", "numpy", "pymavlink", "lcm-")) for p in plot)
