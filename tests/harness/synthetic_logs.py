"""Synthetic LCM logs with known trajectories, for the analysis and replay tests."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import lcm

from antalate_lcm.base.geo import offset
from antalate_lcm.msgs import direction_cmd_t, hlc_error_t, hlc_state_t, mc_state_t, telemetry_t

LAT0, LON0 = 32.7767, 35.0231
T0 = 1_700_000_000_000_000  # µs: the log's first event
CORNERS = {"a-1": (10.0, 10.0), "a-2": (10.0, -10.0), "a-3": (-10.0, -10.0), "a-4": (-10.0, 10.0)}


class LogWriter:
    """Events for a test log, sorted by time on :meth:`write` (a logger writes them in arrival order)."""

    def __init__(self) -> None:
        self.events: list[tuple[float, str, bytes]] = []

    def add(self, t: float, channel: str, data: bytes) -> None:
        self.events.append((t, channel, data))

    def telemetry(
        self,
        t: float,
        agent: str,
        north: float,
        east: float,
        *,
        in_air: bool = True,
        vn: float = 0.0,
        ve: float = 0.0,
        alt: float = 5.0,
    ) -> None:
        msg = telemetry_t()
        msg.header.agent = agent
        msg.lat, msg.lon = offset(LAT0, LON0, north, east)
        msg.alt, msg.in_air, msg.mode = alt, in_air, "GUIDED"
        msg.vn, msg.ve = vn, ve
        self.add(t, f"{agent}/TELEMETRY", msg.encode())

    def mc(self, t: float, agent: str, state: int) -> None:
        msg = mc_state_t()
        msg.header.agent = agent
        msg.state = state
        self.add(t, f"{agent}/MC_STATE", msg.encode())

    def hlc(self, t: float, agent: str, state: int) -> None:
        msg = hlc_state_t()
        msg.header.agent = agent
        msg.state = state
        msg.autopilot = "sim"
        self.add(t, f"{agent}/HLC_STATE", msg.encode())

    def error(self, t: float, agent: str, code: int, severity: int, text: str) -> None:
        msg = hlc_error_t()
        msg.header.agent = agent
        msg.code, msg.severity, msg.text = code, severity, text
        self.add(t, f"{agent}/HLC_ERROR", msg.encode())

    def direction(
        self,
        t: float,
        azimuth: float,
        speed: float = 1.0,
        active: bool = True,
        channel: str = "SWARM/DIRECTION_CMD",
        target: str = "",
    ) -> None:
        msg = direction_cmd_t()
        msg.header.agent = "operator"
        msg.active, msg.azimuth, msg.speed, msg.target = active, azimuth, speed, target
        self.add(t, channel, msg.encode())

    def write(self, path: Path) -> Path:
        log = lcm.EventLog(str(path), "w", overwrite=True)
        for t, channel, data in sorted(self.events, key=lambda e: e[0]):
            log.write_event(T0 + round(t * 1e6), channel, data)
        log.close()
        return path


def square_swarm(
    position: Callable[[str, float], tuple[float, float]] | None = None,
    *,
    until: float = 20.0,
    rtl_at: float = 18.0,
    azimuth: float | None = 80.0,
) -> LogWriter:
    """Four agents on the corners of a 20 m square flying east at 1 m/s (or along ``position``).

    MC: STANDBY at 0 s, MISSION at 2 s (a-4 at 3 s), a-1 RTL at ``rtl_at``: the window is 3..rtl_at.
    The operator broadcasts ``azimuth`` at 1 m/s every second from 2.5 s on (repeats are folded).
    """
    w = LogWriter()
    for name in CORNERS:
        w.mc(0.0, name, mc_state_t.STANDBY)
        w.hlc(0.0, name, hlc_state_t.READY)
        w.mc(3.0 if name == "a-4" else 2.0, name, mc_state_t.MISSION)
        w.hlc(2.0, name, hlc_state_t.AIRBORNE)
        for k in range(int(until * 10) + 1):
            t = k / 10
            n, e = position(name, t) if position else (CORNERS[name][0], CORNERS[name][1] + t)
            w.telemetry(t + 0.001, name, n, e)
        for k in range(int(until * 5)):  # MC republishes at 5 Hz: repeats must fold into one change
            w.mc(
                k / 5 + 0.05,
                name,
                mc_state_t.RTL
                if name == "a-1" and k / 5 >= rtl_at
                else mc_state_t.MISSION
                if k / 5 >= (3.0 if name == "a-4" else 2.0)
                else mc_state_t.STANDBY,
            )
    if azimuth is not None:
        for k in range(3, int(until)):
            w.direction(k - 0.5, azimuth)
    return w
