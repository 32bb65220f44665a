"""The safety filter on the real ArduCopter 4.6.3 (SITL): three vehicles, each flown by its own agent
process through the mavlink adapter, all commanded at their common centroid (docs/safety.md).

Instances 5, 6 and 7 (other SITL modules use 0..4), homes 12-14 m apart. The swarm fence is written
into each vehicle's FENCE_* parameters by its HLC on the ground and read back here on the vehicle's
second link (SERIAL1), as the vehicle itself holds it. Ground truth for the separation is the vehicles'
own GLOBAL_POSITION_INT on that second link, sampled at 10 Hz for the whole flight: its minimum must
stay at or above the radius minus the ArduCopter margin of docs/safety.md. The bus is recorded with
``antalate log`` for the whole flight, and ``antalate analyze LOG --safety AGENT_CONFIG`` must find
the same from the swarm's own telemetry.
"""

from __future__ import annotations

import itertools
import math
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.apps.analysis.logfile import read_log
from antalate_lcm.base.geo import FlatFrame, offset
from antalate_lcm.base.safety.geofence import Geofence
from antalate_lcm.base.safety.separation import separation
from antalate_lcm.msgs import mc_state_t as M
from antalate_lcm.msgs import operator_cmd_t as O
from antalate_lcm.vehicles.mavlink.fence_mirror import fence_parameters
from tests.conftest import Probe
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for
from tests.harness.process import stop_process
from tests.sitl_arducopter.harness import HOME, Copter, one_sitl_swarm_at_a_time

pytestmark = [pytest.mark.netns, pytest.mark.timeout(420)]

#: The mavlink vehicles' separation (antalate_lcm.agent.hlc.safety.VEHICLE_DEFAULTS): 4 m, half-height 2 m.
RADIUS, VERTICAL = 4.0, 2.0
#: docs/safety.md: the margin measured on ArduCopter SITL (velocity loop lag, 10 Hz telemetry).
MARGIN = 1.25  # docs/safety.md: 2.96 m seen twice in the full suite (radius 4 m)
SPEED = 3.0  # m/s, what each behavior commands at the centroid
#: (north, east) m of each home from HOME; the centroid is at (4, 7).
HOMES = {"ac5": (0.0, 0.0), "ac6": (0.0, 14.0), "ac7": (12.0, 7.0)}
CENTROID = (4.0, 7.0)
FENCE: dict[str, Any] = {
    "polygon": [[-30.0, -30.0], [-30.0, 45.0], [40.0, 45.0], [40.0, -30.0]],
    "floor": 0.0,
    "ceiling": 30.0,
    "margin": 2.0,
}
_seq = itertools.count(1)


def fly_at_centroid() -> list[dict[str, Any]]:
    lat, lon = offset(HOME[0], HOME[1], *CENTROID)
    return [
        {
            "name": "attack",
            "behaviors": [
                {
                    "plugin": "tests.harness.bma:FlyAt",
                    "activate_on": ["MISSION"],
                    "params": {"lat": lat, "lon": lon, "speed": SPEED},
                }
            ],
        }
    ]


@pytest.fixture(scope="module", autouse=True)
def _one_sitl_swarm_at_a_time() -> Iterator[None]:
    """Before the vehicles boot (autouse fixtures come first in their scope)."""
    with one_sitl_swarm_at_a_time():
        yield


@pytest.fixture(scope="module")
def copters(sitl_netns: NetNamespace, sitl_dir: Path, sitl_probe: Probe) -> Iterator[dict[str, Copter]]:
    """``sitl_probe`` listens before the agents start: each HLC says once, as it connects, that the
    fence it wrote reads back (HLC_ERROR 14, info), and in one full run at load 8 that came before a
    probe started after the vehicles heard it."""
    safety = {"enabled": True, "origin": [HOME[0], HOME[1]], "fence": FENCE}
    out: dict[str, Copter] = {}
    try:
        for k, (name, (north, east)) in enumerate(HOMES.items()):
            lat, lon = offset(HOME[0], HOME[1], north, east)
            out[name] = Copter(
                sitl_netns,
                sitl_dir / name,
                instance=5 + k,
                name=name,
                home=(lat, lon, HOME[2], HOME[3]),
                bma=fly_at_centroid(),
                sections={"safety": safety},
            )
        for c in out.values():
            c.gcs.set_param("LAND_SPEED", 150)  # shorter landings (cm/s below LAND_ALT_LOW)
        yield out
    finally:
        for c in out.values():
            c.stop()


def swarm_command(probe: Probe, cmd: int) -> None:
    probe.publish(
        "SWARM/OPERATOR_CMD", "operator_cmd_t", header={"seq": next(_seq), "agent": "op"}, command=cmd
    )


def all_mc(probe: Probe, state: int, timeout: float, since: int) -> None:
    for name in HOMES:
        msg = probe.wait(f"{name}/MC_STATE", "mc_state_t", timeout=timeout, since=since, state=state)
        assert msg is not None, f"{name}: MC never reached {state} within {timeout} s"


class Sampler:
    """Every vehicle's own position (SERIAL1) at 10 Hz: the minimum pairwise separation of those in the air.

    While it runs it is the only caller of the `gcs` helpers (one JSON pipe each, no lock: two threads
    on it would take each other's replies); the test reads the vehicles' states from `latest`.
    """

    def __init__(self, copters: dict[str, Copter]) -> None:
        self.copters = copters
        self.frame = FlatFrame(HOME[0], HOME[1])
        self.min_sep = math.inf
        self.min_3d = math.inf
        self.when: Any = None
        self.samples = 0
        self.latest: dict[str, dict[str, Any]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.1):
            where = []
            for name, c in self.copters.items():
                s = self.latest[name] = c.gcs.state()
                if s.get("lat") is None or s["alt"] < 1.0:
                    continue
                north, east = self.frame.to_ne(s["lat"], s["lon"])
                where.append((name, north, east, s["alt"]))
            self.samples += 1
            for i, a in enumerate(where):
                for b in where[i + 1 :]:
                    d = separation(a[1] - b[1], a[2] - b[2], a[3] - b[3], RADIUS / VERTICAL)
                    self.min_3d = min(self.min_3d, math.dist(a[1:], b[1:]))
                    if d < self.min_sep:
                        self.min_sep, self.when = d, (a, b)

    def __enter__(self) -> Sampler:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join(30)
        assert not self._thread.is_alive(), "the sampler is stuck on a gcs call"


def _log_shows_all_landed(log: Path) -> bool:
    """Whether the log being written ends, for every vehicle, in STANDBY and on the ground: the
    analysis's "back in STANDBY on the ground at the end" (the logger flushes every 100 ms; a
    partly written last event is left out by read_log)."""
    agents = read_log(log).agents
    for name in HOMES:
        rec = agents.get(name)
        if rec is None or not rec.mc_states or rec.mc_states[-1].state != "STANDBY":
            return False
        if not rec.telemetry or rec.telemetry[-1].in_air:
            return False
    return True


def _log_tail(log: Path) -> str:
    """Each vehicle's last state and telemetry in the log, for a failure's message."""
    agents = read_log(log).agents
    return "; ".join(
        f"{name}: last MC state {rec.mc_states[-1].state if rec.mc_states else None}, "
        f"in_air {rec.telemetry[-1].in_air if rec.telemetry else None}"
        for name, rec in sorted(agents.items())
    )


def test_three_arducopters_commanded_at_their_centroid_keep_apart_with_the_fence_in_the_vehicle(
    copters: dict[str, Copter], sitl_probe: Probe, sitl_netns: NetNamespace, sitl_dir: Path
) -> None:
    probe = sitl_probe
    started = time.monotonic()
    all_mc(probe, M.STANDBY, timeout=120, since=0)
    # The fence, mirrored on the ground by each HLC (SAFETY INFO), is what each vehicle reports itself.
    frame = FlatFrame(HOME[0], HOME[1])
    fence = Geofence(tuple((n, e) for n, e in FENCE["polygon"]), 0.0, 30.0, 2.0)
    for name, home in HOMES.items():
        said = probe.wait(f"{name}/HLC_ERROR", "hlc_error_t", timeout=120, since=0, code=14, severity=0)
        assert said is not None and "read back" in said["text"], probe.history(
            f"{name}/HLC_ERROR", "hlc_error_t"
        )
        ground = copters[name].gcs.state()  # where the vehicle itself says it stands
        home_ne = frame.to_ne(ground["lat"], ground["lon"])
        assert math.dist(home_ne, home) < 1.0, (name, home_ne, home)
        for param, value in fence_parameters(fence, home_ne, "return").items():
            got = copters[name].gcs.ok(op="get_param", name=param)["value"]
            assert got == pytest.approx(value, abs=0.05), (name, param, got, value)
    ready = time.monotonic()
    mark = probe.mark()
    config = copters["ac5"].agent.path  # every agent's [safety] is the same
    log = sitl_dir / "flight.lcm"
    logger = sitl_netns.antalate(
        "log", str(config), "-o", str(log), stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    assert logger.stdout is not None and "logging bus" in logger.stdout.readline()
    with Sampler(copters) as sampler:
        swarm_command(probe, O.TAKEOFF)
        all_mc(probe, M.MISSION, timeout=150, since=mark)
        in_mission = time.monotonic()
        time.sleep(20.0)  # every behavior flies at the centroid
        closest_in_mission = sampler.min_sep
        rtl = probe.mark()
        swarm_command(probe, O.RTL)
        all_mc(probe, M.STANDBY, timeout=150, since=rtl)
        assert wait_for(lambda: not any(sampler.latest[n]["armed"] for n in HOMES), 30, 0.5)
        # The logger reads the bus beside the probe, and may still be behind it (a loaded machine):
        # stopped now, the log can end before an agent's last state or telemetry. Stopped once the
        # log itself shows every agent in STANDBY on the ground, what the analysis below reads.
        assert wait_for(lambda: _log_shows_all_landed(log), 60, 0.5), _log_tail(log)
    landed = time.monotonic()
    stop_process(logger)  # SIGTERM reaches lcm-logger itself: the file is complete
    analysis = subprocess.run(
        [sys.executable, "-m", "antalate_lcm.cli", "analyze", str(log), "--safety", str(config)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout
    section = analysis[analysis.index("safety (radius") :]
    print(f"\nantalate analyze {log.name} --safety {config.name}:\n{section}")
    reports = [
        e["text"]
        for name in HOMES
        for e in probe.history(f"{name}/HLC_ERROR", "hlc_error_t", since=mark)
        if e["code"] == 14
    ]
    print(
        f"\n3 ArduCopter SITL at their centroid: min separation {sampler.min_sep:.2f} m"
        f" (in MISSION {closest_in_mission:.2f} m), 3-D {sampler.min_3d:.2f} m over {sampler.samples} samples,"
        f" radius {RADIUS:g} m; {len(reports)} SAFETY reports; boot to fence read back {ready - started:.0f} s,"
        f" take-off to MISSION {in_mission - ready:.0f} s, RTL to landed {landed - in_mission - 20:.0f} s;"
        f" closest {sampler.when}"
    )
    assert any("modified by separation" in r for r in reports), reports
    assert sampler.min_sep >= RADIUS - MARGIN, sampler.when
    assert f"radius - margin = {RADIUS - MARGIN:.2f} m: OK" in section, section
    assert "fence breaches     0" in section and "3 of 3 agent(s) flew MISSION; 3 back in STANDBY" in section
    # every one came home through the filter and landed within a couple of metres of its home
    for name, home in HOMES.items():
        s = copters[name].gcs.state()
        north, east = frame.to_ne(s["lat"], s["lon"])
        assert math.hypot(north - home[0], east - home[1]) < 2.5, (name, north, east)
