"""The shipped peer behaviors fly the same in every launch mode (docs/behaviors.md, "Launch modes").

8 simulated agents fly ``gathering`` and ``flocking`` with the same config (only the bus URL differs)
in one process, over two processes (``--processes 2``), one agent per host on a simulated LAN, and
over a Zenoh router; each flight is recorded by ``lcm-logger`` and judged from its telemetry only
(tests/agent/swarm_flight.py): every agent's peer sensor named all 7 peers, the gathering ends within a
5 m radius with no two agents ever nearer than the configured 3 m, the flock's polarisation exceeds
0.9. Every flight runs with a swarm key, and no agent may log a replayed message: its own telemetry
reaches it once.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from antalate_lcm.runtime.cli import native_lcm_tool
from tests.agent import swarm_flight as sf
from tests.conftest import MCAST_URL
from tests.harness.netns import NetNamespace, netns_unavailable
from tests.lan.conftest import lan_reason
from tests.lan.topology import Lan

LAN_URL = "udpm://239.255.76.67:7667?ttl=1"
ZENOH_PORT = 7447
ZENOH_URL = f"zenoh://?connect=tcp/127.0.0.1:{ZENOH_PORT}&mode=client"
#: s a flight may take from start to every agent returning (takeoff, mission, start-up under load).
FLIGHT_TIMEOUT = 90.0
MODES = ["one-process", "processes-2", "lan", "zenoh"]


def _wait_for_rtl(log: Path, procs: list[subprocess.Popen[str]], outputs: list[Path]) -> sf.Flight:
    deadline = time.monotonic() + FLIGHT_TIMEOUT
    while time.monotonic() < deadline:
        time.sleep(1.0)
        dead = [p for p in procs if p.poll() is not None]
        assert not dead, "an agent process exited:\n" + "\n".join(o.read_text()[-3000:] for o in outputs)
        if log.exists() and sf.read_flight(log).all_returning():
            return sf.read_flight(log)
    flight = sf.read_flight(log) if log.exists() else sf.Flight()
    raise AssertionError(f"no RTL within {FLIGHT_TIMEOUT} s; states: {flight.states}")


def _logger(url: str, log: Path) -> list[str]:
    return [native_lcm_tool("lcm-logger"), f"--lcm-url={url}", "--force", str(log)]


def _in_namespace(mode: str, behavior: str, tmp: Path) -> tuple[sf.Flight, list[Path]]:
    """One process, --processes 2, or Zenoh: ``antalate agent --agents 8`` in a private namespace."""
    reason = netns_unavailable()
    if reason:
        pytest.skip(f"no private network namespace: {reason}")
    doc = sf.config_doc(behavior, MCAST_URL, tmp / "state")
    args = ["--agents", str(sf.AGENTS), "--spacing", str(sf.SPACING)]
    if mode == "zenoh":
        pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install -e '.[dev]')")
        # The swarm meets on Zenoh; what it says is also sent to a multicast bus on lo for the logger
        # (publish to every bus of a topic, subscribe on the first: peers are heard over Zenoh only).
        doc["buses"] = {"swarm": ZENOH_URL, "log": MCAST_URL}
        doc["topics"] = {
            "default_bus": "swarm",
            **{t: ["swarm", "log"] for t in ("TELEMETRY", "MC_STATE", "PEER_SCAN")},
        }
        args += ["--processes", "2"]
    elif mode == "processes-2":
        args += ["--processes", "2"]
    cfg = sf.write_config(tmp / "swarm.toml", doc)
    log, out = tmp / "flight.lcm", tmp / "agents.log"
    with NetNamespace() as ns, open(out, "w") as sink:
        procs = []
        if mode == "zenoh":
            procs.append(
                ns.antalate(
                    "router", "--listen", f"tcp/127.0.0.1:{ZENOH_PORT}", stdout=sink, stderr=subprocess.STDOUT
                )
            )
        ns.popen(_logger(MCAST_URL, log), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        procs.append(
            ns.antalate(
                "--log-level", "INFO", "agent", str(cfg), *args, stdout=sink, stderr=subprocess.STDOUT
            )
        )
        return _wait_for_rtl(log, procs, [out]), [out]


def _on_lan(behavior: str, tmp: Path) -> tuple[sf.Flight, list[Path]]:
    """One agent per host: 8 vehicle computers and a recorder on one simulated LAN."""
    reason = lan_reason()
    if reason:
        pytest.skip(f"no simulated LAN: {reason}")
    log = tmp / "flight.lcm"
    outputs = [tmp / f"{name}.log" for name in sf.NAMES]
    with Lan([*sf.NAMES, "rec"]) as lan:
        lan["rec"].popen(_logger(LAN_URL, log))
        procs = []
        for i, name in enumerate(sf.NAMES):
            cfg = sf.write_config(
                tmp / f"{name}.toml", sf.config_doc(behavior, LAN_URL, tmp / f"{name}-state", index=i)
            )
            procs.append(lan[name].antalate("--log-level", "INFO", "agent", str(cfg), log=outputs[i]))
        return _wait_for_rtl(log, procs, outputs), outputs


FLY: dict[str, Callable[[str, Path], tuple[sf.Flight, list[Path]]]] = {
    "one-process": lambda b, tmp: _in_namespace("one-process", b, tmp),
    "processes-2": lambda b, tmp: _in_namespace("processes-2", b, tmp),
    "zenoh": lambda b, tmp: _in_namespace("zenoh", b, tmp),
    "lan": _on_lan,
}


@pytest.mark.timeout(180)
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("behavior", ["gathering", "flocking"])
def test_peer_behaviors_fly_the_same_in_every_launch_mode(behavior: str, mode: str, tmp_path: Path) -> None:
    flight, outputs = FLY[mode](behavior, tmp_path)
    verdict = sf.judge(flight)
    print(f"{behavior} {mode}: {verdict}")  # the measured figures, for docs/behaviors.md (pytest -s)
    assert verdict.heard == dict.fromkeys(sf.NAMES, sf.AGENTS - 1), verdict.heard
    separation, when, pair = verdict.min_separation
    assert separation >= sf.SEPARATION, f"{pair} came within {separation:.2f} m at t = {when:.1f} s"
    if behavior == "gathering":
        assert verdict.final_radius < 5.0, verdict
    else:
        assert verdict.polarisation > 0.9, verdict
    text = "".join(o.read_text() for o in outputs)
    assert "replayed or out of order" not in text  # an agent's own telemetry reaches it once
    assert "Traceback" not in text
