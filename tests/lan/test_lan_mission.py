"""Five vehicle computers and an operator laptop on one (simulated) LAN, each agent with the example
config of its host (``examples/lan/``), the operator acknowledging commands as the console does.

* a whole mission: take off all, two direction commands, RTL, everyone back in STANDBY;
* the same with 20 % of the frames dropped by the switch: every command acknowledged (by resending
  it), every mission completed;
* a vehicle cut off the LAN mid-mission: the operator sees it go stale, while its own nodes, each in
  its own process on its host, keep flying it over the host's local bus.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import lcm
import pytest

from antalate_lcm.apps.analysis import analyze, read_log
from tests.lan.swarm import VEHICLES, LanSwarm

pytestmark = [pytest.mark.lan, pytest.mark.timeout(150), pytest.mark.usefixtures("need_lan")]

DIRECTIONS = ((90.0, 2.0, 5.0), (0.0, 2.0, 5.0))  # azimuth (deg), speed (m/s), seconds


def fly_mission(swarm: LanSwarm, *, deaf: str | None = None) -> dict[str, Any]:
    """Take off all, fly :data:`DIRECTIONS`, RTL all; every command must be acknowledged by all.

    With ``deaf``, the switch drops every frame to that vehicle for 1.5 s from the TAKEOFF on
    (less than the operator's 2 s staleness): it surely misses the first send, and only a resend
    can take it off.
    """
    op = swarm.op
    assert op is not None
    op.wait_all(VEHICLES, "STANDBY", timeout=30)
    if deaf:
        swarm.lan.set_loss(100, host=deaf)
    op.command("TAKEOFF", altitude=3.0)
    if deaf:
        time.sleep(1.5)
        swarm.lan.set_loss(None, host=deaf)
    op.wait_all(VEHICLES, "MISSION", timeout=30)
    for azimuth, speed, seconds in DIRECTIONS:
        op.direction(azimuth, speed)
        time.sleep(seconds)
    op.command("RTL")
    op.wait_all(VEHICLES, "STANDBY", timeout=40)
    status = op.wait(lambda s: s["pending"] == 0, timeout=10, what="no command pending")
    for cmd in status["commands"]:
        assert cmd["status"] == "acked", cmd
        assert cmd["expected"] == list(VEHICLES) == cmd["acked"], cmd
    return status


def check_log(swarm: LanSwarm, *, max_error: float) -> None:
    """What the operator heard, through ``antalate analyze``: every agent's whole mission, and the
    swarm's drift along each commanded direction."""
    swarm.stop_loggers()
    record = read_log(swarm.lan_log)
    for name in VEHICLES:
        states = [c.state for c in record.agents[name].mc_states]
        flown = [s for s in states if s in ("STANDBY", "TAKEOFF", "MISSION", "RTL")]
        assert flown[:4] == ["STANDBY", "TAKEOFF", "MISSION", "RTL"] and states[-1] == "STANDBY", (
            name,
            states,
        )
    result = analyze(record)
    assert [d.azimuth for d in result.drift] == [a for a, _, _ in DIRECTIONS]
    for d in result.drift:
        assert d.agents == len(VEHICLES)
        assert d.error is not None and abs(d.error) <= max_error, d
        assert d.speed == pytest.approx(2.0, rel=0.35), d


def test_mission_over_the_lan(tmp_path: Path) -> None:
    with LanSwarm(tmp_path) as swarm:
        fly_mission(swarm)
        check_log(swarm, max_error=20.0)
        # the station on the operator laptop heard every vehicle's OSC across the LAN
        assert "Traceback" not in swarm.log_text("station")


def test_mission_with_20_percent_loss(tmp_path: Path) -> None:
    with LanSwarm(tmp_path, loss=20) as swarm:
        status = fly_mission(swarm, deaf="uav-2")
        assert swarm.lan.dropped() > 100  # the switch really dropped frames
        sends = {c["command"]: c["sends"] for c in status["commands"]}
        print(f"sends per command with 20 % loss: {sends}; frames dropped: {swarm.lan.dropped()}")
        assert sends["TAKEOFF"] >= 2  # uav-2 missed the first: acknowledged only thanks to the resend
        # The turn from east to north alone costs ~14 deg over the 5 s span (lossless). The operator
        # repeats the direction every second, so a vehicle that misses it twice (4 % per vehicle and
        # change at 20 % loss) flies the old direction 2 s longer: 10-12 deg typical here, 37 deg seen
        # once in 9 runs. 45 deg still tells the commanded heading from the one before (90 deg away).
        check_log(swarm, max_error=45.0)


def _events(path: Path, channel: str) -> list[float]:
    """Times (s since the epoch) of every event on ``channel`` in an LCM log."""
    log = lcm.EventLog(str(path), "r")
    try:
        return [ev.timestamp / 1e6 for ev in log if ev.channel == channel]
    finally:
        log.close()


def _max_gap(times: list[float], start: float, end: float) -> float:
    inside = [start, *(t for t in times if start < t < end), end]
    return max(b - a for a, b in zip(inside, inside[1:], strict=False))


def test_vehicle_cut_off_is_stale_to_the_operator_and_flies_on(tmp_path: Path) -> None:
    cut = "uav-3"
    with LanSwarm(tmp_path, split=[cut], local_log=[cut]) as swarm:
        op = swarm.op
        assert op is not None
        op.wait_all(VEHICLES, "STANDBY", timeout=30)
        op.command("TAKEOFF", altitude=3.0)
        op.wait_all(VEHICLES, "MISSION", timeout=30)
        op.direction(90.0, 1.0)
        time.sleep(1.0)

        t_cut = time.time()
        swarm.lan.cut(cut)
        status = op.wait(lambda s: cut in s["stale"], timeout=6, what=f"{cut} stale")
        noticed = time.time() - t_cut
        assert 1.5 <= noticed <= 4.0, noticed  # stale after 2 s of silence
        assert status["stale"] == [cut]  # the others are heard as before
        time.sleep(4.0)
        t_back = time.time()
        swarm.lan.restore(cut)
        status = op.wait(lambda s: cut not in s["stale"], timeout=8, what=f"{cut} heard again")
        assert status["agents"][cut]["mc"] == "MISSION"  # it flew its mission all along
        op.command("RTL")
        op.wait_all(VEHICLES, "STANDBY", timeout=40)
        status = op.wait(lambda s: s["pending"] == 0, timeout=10, what="no command pending")
        assert all(c["status"] == "acked" and c["acked"] == list(VEHICLES) for c in status["commands"])

        swarm.stop_loggers()
        # What the vehicle's own nodes said to each other on its local bus while it was cut off:
        # the MC stayed in MISSION, the HLC AIRBORNE, telemetry and the BMA's velocity commands
        # (HLC, MC and BMA are three processes here) never paused, and the vehicle kept moving.
        local = swarm.local_log_path(cut)
        record = read_log(local)
        t0 = record.start_utime / 1e6
        a, b = t_cut - t0 + 0.2, t_back - t0
        agent = record.agents[cut]
        assert [c.state for c in agent.mc_states if a <= c.t <= b] == []
        assert [c.state for c in agent.mc_states if c.t < a][-1] == "MISSION"
        assert [c.state for c in agent.hlc_states if a <= c.t <= b] == []
        assert [c.state for c in agent.hlc_states if c.t < a][-1] == "AIRBORNE"
        tel = [s for s in agent.telemetry if a <= s.t <= b]
        assert tel and all(s.in_air for s in tel)
        assert _max_gap([s.t + t0 for s in tel], a + t0, b + t0) < 0.5
        moved = math.dist(*((s.lat * 111_000, s.lon * 93_000) for s in (tel[0], tel[-1])))
        assert moved > 2.0, moved  # ~1 m/s east for ~5 s
        velocity = _events(local, f"{cut}/VELOCITY_CMD")
        assert _max_gap(velocity, a + t0, b + t0) < 0.5
        # ... while the operator heard nothing from it
        heard = _events(swarm.lan_log, f"{cut}/TELEMETRY")
        assert _max_gap(heard, t_cut + 0.2, t_back - 0.2) >= (t_back - t_cut) - 0.5
        assert "Traceback" not in "".join(swarm.log_text(f"{cut}-{n}") for n in ("hlc", "mc", "bma", "osc"))
