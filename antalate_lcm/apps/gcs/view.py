"""Each agent as a MAVLink vehicle, and a ground station's commands as antalate's (pure).

A ground station (QGroundControl, MAVProxy, Mission Planner) shows a vehicle per MAVLink system id
from its HEARTBEAT and draws it from GLOBAL_POSITION_INT; so each agent gets its own system id and
the messages below, built from what the agent publishes. The vehicle is presented as an ArduCopter
(``MAV_AUTOPILOT_ARDUPILOTMEGA``, ``MAV_TYPE_QUADROTOR``) because that is what makes every ground
station name its mode; the mode is the ArduCopter mode nearest to the MC state (:data:`MC_MODES`,
docs/tools.md), and the exact MC and HLC states go out as STATUSTEXT when they change.

Message fields follow the MAVLink common set (pymavlink's ``ardupilotmega`` dialect, the one the
MAVLink adapter speaks: ``vehicles/mavlink/dialect.py``); units as there: GLOBAL_POSITION_INT lat/lon
in 1e-7 degrees, altitudes in mm, velocities in cm/s, heading in centidegrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.msgs import hlc_error_t, hlc_state_t, mc_state_t, telemetry_t
from antalate_lcm.vehicles.mavlink.dialect import COPTER_MODES
from antalate_lcm.wire.vocabulary import Command, HlcState, McState, name_of

#: MC state -> the ArduCopter mode a ground station shows (HEARTBEAT custom_mode).
MC_MODES: dict[int, str] = {
    McState.INIT: "STABILIZE",
    McState.STANDBY: "GUIDED",  # on the ground, waiting for a command under computer control
    McState.TAKEOFF: "GUIDED",
    McState.MISSION: "AUTO",  # the behaviors fly it
    McState.RTL: "RTL",
    McState.LAND: "LAND",
    McState.MANUAL: "STABILIZE",  # a pilot flies it
    McState.ERROR: "LOITER",
    McState.HOLD: "BRAKE",
    McState.HLC_LOST: "LOITER",  # the vehicle is on its own failsafe; system_status says CRITICAL
}
#: ArduCopter modes a ground station may ask for, and the operator command each becomes.
MODE_COMMANDS: dict[int, Command] = {COPTER_MODES["RTL"]: Command.RTL, COPTER_MODES["LAND"]: Command.LAND}
#: hlc_error_t severity -> MAV_SEVERITY.
SEVERITIES = {
    hlc_error_t.INFO: mav.MAV_SEVERITY_INFO,
    hlc_error_t.WARNING: mav.MAV_SEVERITY_WARNING,
    hlc_error_t.ERROR: mav.MAV_SEVERITY_ERROR,
    hlc_error_t.CRITICAL: mav.MAV_SEVERITY_CRITICAL,
}
_CRITICAL_MC = frozenset({McState.ERROR, McState.HLC_LOST})
_CRITICAL_HLC = frozenset({HlcState.LOW_BATTERY, HlcState.LLC_DOWN})
#: STATUSTEXT holds 50 characters.
TEXT_MAX = 50


@dataclass
class GcsVehicle:
    """What the view knows of one agent."""

    name: str
    sysid: int
    heard: float = 0.0
    telemetry: telemetry_t | None = None
    mc: int | None = None
    hlc: int | None = None
    autopilot: str = ""


@dataclass(frozen=True)
class OperatorRequest:
    """A ground station's command as the operator command it becomes (``target`` "" = every agent)."""

    command: Command
    target: str
    altitude: float


@dataclass(frozen=True)
class GcsRefusal:
    result: int
    text: str


def _text(text: str) -> bytes:
    return text.encode("utf-8")[:TEXT_MAX]


def _int(value: float, scale: float, lo: int, hi: int) -> int:
    """A scaled float as a MAVLink integer field, clamped; a non-finite value as 0."""
    if not math.isfinite(value):
        return 0
    return max(lo, min(hi, round(value * scale)))


class GcsView:
    """Agents by name with their system ids (in the order first heard, from ``sysid_base``), what to
    send a ground station for them, and what a ground station's command means. Time comes in."""

    def __init__(
        self,
        *,
        sysid_base: int = 101,
        stale_after: float = 3.0,
        hide_autopilots: frozenset[str] = frozenset(),
    ) -> None:
        if not 1 <= sysid_base <= 255:
            raise ValueError(f"a MAVLink system id is 1..255, not {sysid_base}")
        self.sysid_base = sysid_base
        self.stale_after = stale_after
        self.hide_autopilots = hide_autopilots
        self.vehicles: dict[str, GcsVehicle] = {}
        self._by_sysid: dict[int, GcsVehicle] = {}
        #: Agents heard when every system id up to 255 was taken (not shown).
        self.unplaced: set[str] = set()

    def _vehicle(self, name: str, now: float) -> GcsVehicle | None:
        v = self.vehicles.get(name)
        if v is None:
            sysid = self.sysid_base + len(self.vehicles)
            if sysid > 255:
                self.unplaced.add(name)
                return None
            v = self.vehicles[name] = self._by_sysid[sysid] = GcsVehicle(name, sysid)
        v.heard = now
        return v

    def shown(self, v: GcsVehicle, now: float) -> bool:
        return now - v.heard <= self.stale_after and v.autopilot not in self.hide_autopilots

    # ------------------------------------------------------------------ agent -> ground station
    def on_message(self, agent: str, msg: Any, now: float, boot_ms: int) -> list[tuple[int, Any]]:
        """``(system id, MAVLink message)`` pairs to send now for a message an agent published."""
        v = self._vehicle(agent, now)
        if v is None:
            return []
        out: list[tuple[int, Any]] = []
        if isinstance(msg, telemetry_t):
            v.telemetry = msg
            out += [(v.sysid, self.global_position(msg, boot_ms)), (v.sysid, self.vfr_hud(msg))]
        elif isinstance(msg, mc_state_t):
            if v.mc != msg.state:
                name = name_of(McState, msg.state) or f"?{msg.state}"
                out.append(
                    (v.sysid, self.statustext(mav.MAV_SEVERITY_NOTICE, f"MC {name} {msg.reason}".strip()))
                )
            v.mc = int(msg.state)
        elif isinstance(msg, hlc_state_t):
            if v.hlc != msg.state:
                name = name_of(HlcState, msg.state) or f"?{msg.state}"
                out.append(
                    (v.sysid, self.statustext(mav.MAV_SEVERITY_INFO, f"HLC {name} {msg.reason}".strip()))
                )
            v.hlc, v.autopilot = int(msg.state), str(msg.autopilot)
        elif isinstance(msg, hlc_error_t):
            severity = SEVERITIES.get(msg.severity, mav.MAV_SEVERITY_ERROR)
            out.append((v.sysid, self.statustext(severity, f"[{msg.code}] {msg.text}")))
        return [(sysid, m) for sysid, m in out if self.shown(v, now)]

    def tick(self, now: float) -> list[tuple[int, Any]]:
        """Once a second: HEARTBEAT and SYS_STATUS of every agent heard lately (a silent agent's
        vehicle stops beating, and the ground station says its link is lost)."""
        out: list[tuple[int, Any]] = []
        for v in self.vehicles.values():
            if self.shown(v, now):
                out += [(v.sysid, self.heartbeat(v)), (v.sysid, self.sys_status(v))]
        return out

    @staticmethod
    def heartbeat(v: GcsVehicle) -> Any:
        t = v.telemetry
        mode = MC_MODES.get(v.mc, "STABILIZE") if v.mc is not None else "STABILIZE"
        base = (
            mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            | mav.MAV_MODE_FLAG_GUIDED_ENABLED
            | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
        )
        if t is not None and t.armed:
            base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
        if v.mc in _CRITICAL_MC or v.hlc in _CRITICAL_HLC:
            status = mav.MAV_STATE_CRITICAL
        elif v.hlc is None or v.hlc == HlcState.INIT:
            status = mav.MAV_STATE_BOOT
        elif t is not None and t.in_air:
            status = mav.MAV_STATE_ACTIVE
        else:
            status = mav.MAV_STATE_STANDBY
        return mav.MAVLink_heartbeat_message(
            mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base, COPTER_MODES[mode], status, 3
        )

    @staticmethod
    def sys_status(v: GcsVehicle) -> Any:
        battery = float(v.telemetry.battery) if v.telemetry is not None else -1.0
        remaining = _int(battery, 1, 0, 100) if math.isfinite(battery) and battery >= 0 else -1
        return mav.MAVLink_sys_status_message(0, 0, 0, 0, 0xFFFF, -1, remaining, 0, 0, 0, 0, 0, 0)

    @staticmethod
    def global_position(t: telemetry_t, boot_ms: int) -> Any:
        # antalate knows the altitude above home only: it is both alt (no MSL) and relative_alt
        alt_mm = _int(t.alt, 1000, -(2**31), 2**31 - 1)
        heading = _int(t.heading, 100, 0, 35999) if math.isfinite(t.heading) else 0xFFFF
        return mav.MAVLink_global_position_int_message(
            boot_ms & 0xFFFFFFFF,
            _int(t.lat, 1e7, -900_000_000, 900_000_000),
            _int(t.lon, 1e7, -1_800_000_000, 1_800_000_000),
            alt_mm,
            alt_mm,
            _int(t.vn, 100, -32768, 32767),
            _int(t.ve, 100, -32768, 32767),
            _int(t.vd, 100, -32768, 32767),
            heading,
        )

    @staticmethod
    def vfr_hud(t: telemetry_t) -> Any:
        ground = math.hypot(t.vn, t.ve) if math.isfinite(t.vn) and math.isfinite(t.ve) else 0.0
        climb = -t.vd if math.isfinite(t.vd) else 0.0
        heading = _int(t.heading, 1, 0, 359)
        alt = t.alt if math.isfinite(t.alt) else 0.0
        return mav.MAVLink_vfr_hud_message(ground, ground, heading, 0, alt, climb)

    @staticmethod
    def statustext(severity: int, text: str) -> Any:
        return mav.MAVLink_statustext_message(severity, _text(text))

    # ------------------------------------------------------------------ ground station -> agents
    def targets(self, target_system: int, now: float) -> list[GcsVehicle]:
        """The vehicles a command to ``target_system`` is for (0: all shown); [] when it is none of
        ours (a real autopilot's system id: its own MAVLink answers)."""
        if target_system == 0:
            return [v for v in self.vehicles.values() if self.shown(v, now)]
        v = self._by_sysid.get(target_system)
        return [v] if v is not None and self.shown(v, now) else []

    def request(
        self, target_system: int, command: int, params: tuple[float, ...], now: float
    ) -> OperatorRequest | GcsRefusal | None:
        """What a COMMAND_LONG (or SET_MODE, as MAV_CMD_DO_SET_MODE) asks of antalate; None when it
        is for no agent of ours."""
        vehicles = self.targets(target_system, now)
        if not vehicles:
            return None
        target = "" if target_system == 0 else vehicles[0].name
        if command == mav.MAV_CMD_NAV_TAKEOFF:
            altitude = params[6] if len(params) > 6 else 0.0
            if not math.isfinite(altitude) or altitude < 0:
                return GcsRefusal(mav.MAV_RESULT_DENIED, f"takeoff altitude {altitude} is not a height")
            return OperatorRequest(Command.TAKEOFF, target, altitude)
        if command == mav.MAV_CMD_NAV_LAND:
            return OperatorRequest(Command.LAND, target, 0.0)
        if command == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return OperatorRequest(Command.RTL, target, 0.0)
        if command == mav.MAV_CMD_DO_SET_MODE:
            mode = int(params[1]) if len(params) > 1 and math.isfinite(params[1]) else -1
            if mode in MODE_COMMANDS:
                return OperatorRequest(MODE_COMMANDS[mode], target, 0.0)
            return GcsRefusal(mav.MAV_RESULT_DENIED, "antalate takes only the modes RTL and LAND")
        return GcsRefusal(mav.MAV_RESULT_UNSUPPORTED, "antalate takes TAKEOFF, LAND, RTL")
