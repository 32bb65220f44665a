"""`SimAutopilot`: an in-process kinematic quadcopter, the default vehicle (docs/design.md §7, ``sim``).

It is meant for running the whole framework (and swarms of 200 agents) on one laptop, and for
testing the HLC against faults that are hard to provoke on real hardware.

The model
---------
* Position is kept in metres north/east of home and altitude above home; lat/lon are derived with
  `antalate_lcm.base.geo.FlatFrame` (a tangent-plane approximation: centimetres off at 1 km, plenty
  for a flying field, and a few multiplications per call).
* Velocity set-points (GUIDED, `set_velocity`) are followed with a first-order lag of time constant
  ``tau``; the horizontal set-point is limited to ``max_speed``, the vertical one to ``climb_rate`` up
  and ``descent_rate`` down. Like ArduCopter, a set-point expires after ``velocity_hold`` seconds.
* Manoeuvres the autopilot runs itself -- takeoff climb, landing descent, the RTL return leg -- are
  rate-limited kinematics (exactly ``climb_rate``, ``descent_rate``, ``rtl_speed``, stopping exactly on
  target), which keeps their timing predictable; horizontal drift is braked with the same lag.
* Modes are reported as ArduCopter names: ``GUIDED``, ``LAND``, ``RTL``, and ``LOITER`` for a pilot.
  RTL flies home at the current altitude (or first climbs to ``rtl_altitude`` if that is higher),
  then lands, still in RTL mode. Landing disarms ``land_disarm_delay`` s after touchdown; an armed
  vehicle that does not take off within ``auto_disarm_delay`` s disarms itself. An empty battery in
  the air forces a LAND (the autopilot's own failsafe).
* Battery drains ``drain_flying`` %/min in the air and ``drain_idle`` %/min on the ground.

Time
----
The simulation advances lazily: whenever `state()` or a command is called, it integrates from the
previous call to ``clock()`` (scaled by ``time_scale``) in steps of at most ``max_step`` seconds
(in one go while idle on the ground, and in GUIDED flight when no set-point expiry, empty battery or
touchdown can fall inside the interval: the lag is exact for any step, see ``_one_step``). Nothing runs between calls, so hundreds of sims cost nothing
while idle, and tests drive time with a fake clock. Autopilot timers (auto-disarm, velocity hold, ...)
run on simulated time; `AutopilotState.link_age` is in real (clock) seconds, as the HLC perceives it.

Fault injection (params at construction, and methods at run time)
-----------------------------------------------------------------
``link_loss`` / `set_link_loss`: the vehicle stops answering: `state()` repeats the last snapshot
with a growing ``link_age`` and commands raise `AutopilotError` (the vehicle itself flies on).
``refuse_arm`` / `set_refuse_arm`: `arm()` returns False. ``battery`` / `set_battery`: the level.
`pilot_takeover`: mode LOITER, not autonomous; with ``takeover_autoland`` the "pilot" lands after
``takeover_land_delay`` s. ``time_scale`` / `set_time_scale`: simulated seconds per real second.
`trigger_failsafe(mode, reason)`: the autopilot's own failsafe (fence, battery, EKF, GCS) switches to
``RTL``, ``LAND`` or ``BRAKE`` (holds position) and reports `AutopilotState.failsafe` = reason until
it touches down or is commanded another mode. `set_state_error(text)`: `state()` raises
``RuntimeError(text)`` (an adapter bug) until called with None; the vehicle flies on meanwhile.

Battery voltage: a ``cells``-cell pack whose voltage per cell falls linearly from 4.2 V (100%) to
3.4 V (0%), minus ``voltage_sag`` V per cell in the air (a tired or cold pack sags under load while
its percentage still reads well); ``cells = 0`` reports no voltage. ``battery_warning_at`` (percent,
0 = never): at or below it the vehicle sets `AutopilotState.battery_warning` (its own low-battery
verdict, like ArduPilot's BATT_LOW_VOLT/BATT_LOW_MAH). An empty battery in the air forces LAND with
failsafe "battery empty".

Scheduled faults, in s of simulated flight after takeoff (0 = never), for tests that run the sim in
another process: ``link_loss_after`` (lasting ``link_loss_for`` s, 0 = for good), ``takeover_after``,
``failsafe_after`` (``failsafe_mode`` rtl|land|brake, ``failsafe_reason``), ``state_error_after``
(lasting ``state_error_for`` s, 0 = for good). Each fires once per sim.
"""

from __future__ import annotations

import enum
import json
import math
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from antalate_lcm.autopilot.base import (
    Autopilot,
    AutopilotError,
    AutopilotState,
    Clock,
    FlightMode,
    Frame,
    check_takeoff_altitude,
    check_velocity,
)
from antalate_lcm.base.geo import FlatFrame, body_to_ne, wrap_360

#: The scheduled faults' parameters (s of flight after takeoff, 0 = never).
_SCHEDULED_FAULTS = ("takeover_after", "link_loss_after", "failsafe_after", "state_error_after")

#: Parameters and their defaults (``[hlc.autopilot_params]`` with ``autopilot = "sim"``).
DEFAULTS: dict[str, Any] = {
    "home_lat": 32.7767,  # deg; Technion, Haifa
    "home_lon": 35.0231,  # deg
    "heading": 0.0,  # deg, initial
    "tau": 0.5,  # s, time constant of the velocity response
    "climb_rate": 2.5,  # m/s
    "descent_rate": 1.5,  # m/s
    "max_speed": 10.0,  # m/s horizontal
    "max_yaw_rate": 180.0,  # deg/s
    "rtl_speed": 5.0,  # m/s
    "rtl_altitude": 0.0,  # m; 0 = return at the current altitude
    "battery": 100.0,  # percent, initial
    "drain_flying": 4.0,  # percent per minute in the air
    "drain_idle": 0.1,  # percent per minute on the ground
    "auto_disarm_delay": 10.0,  # s armed on the ground before disarming
    "land_disarm_delay": 0.5,  # s after touchdown
    "velocity_hold": 3.0,  # s a velocity set-point stays valid
    "takeover_autoland": True,  # after pilot_takeover(), the pilot lands
    "takeover_land_delay": 2.0,  # s
    "link_loss": False,
    "refuse_arm": False,
    "time_scale": 1.0,
    "max_step": 0.05,  # s of simulated time per integration step
    # Scheduled faults, in s of flight after takeoff (0 = never), for tests that run the sim in
    # another process where the fault-injection methods cannot be called.
    "link_loss_after": 0.0,
    "link_loss_for": 0.0,  # s the scheduled link loss lasts; 0 = for good
    "takeover_after": 0.0,
    "failsafe_after": 0.0,
    "failsafe_mode": "rtl",  # rtl | land | brake
    "failsafe_reason": "fence breach",
    "state_error_after": 0.0,
    "state_error_for": 0.0,  # s state() keeps raising; 0 = for good
    # Battery voltage model (see the module docstring).
    "cells": 4,  # cells in series; 0 = the vehicle reports no voltage
    "voltage_sag": 0.0,  # V per cell lost under load in the air
    "battery_warning_at": 0.0,  # percent at or below which the vehicle warns; 0 = never
    # A file where the vehicle's state is kept, so that a restarted HLC process finds the vehicle
    # where it was (a real vehicle outlives the software that flies it); "" = none.
    "state_file": "",
}


def _num(key: str, *, ge: float | None = None, gt: float | None = None, le: float | None = None) -> Any:
    return Field(default=DEFAULTS[key], allow_inf_nan=False, ge=ge, gt=gt, le=le)


class Params(BaseModel):
    """The ``[hlc.autopilot_params]`` table of ``autopilot = "sim"``: every key of `DEFAULTS`, typed and bounded.

    Validated when the config is loaded (`Autopilot.params_model`): a negative delay or rate, a
    battery over 100 % or ``link_loss = "yes"`` stops the program naming the key.
    """

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)

    home_lat: float = _num("home_lat", ge=-90, le=90)
    home_lon: float = _num("home_lon", ge=-180, le=180)
    heading: float = _num("heading")
    tau: float = _num("tau", gt=0)
    climb_rate: float = _num("climb_rate", gt=0)
    descent_rate: float = _num("descent_rate", gt=0)
    max_speed: float = _num("max_speed", gt=0)
    max_yaw_rate: float = _num("max_yaw_rate", ge=0)
    rtl_speed: float = _num("rtl_speed", gt=0)
    rtl_altitude: float = _num("rtl_altitude", ge=0)
    battery: float = _num("battery", ge=0, le=100)
    drain_flying: float = _num("drain_flying", ge=0)
    drain_idle: float = _num("drain_idle", ge=0)
    #: > 0: at 0 the vehicle would disarm between arm() and takeoff().
    auto_disarm_delay: float = _num("auto_disarm_delay", gt=0)
    land_disarm_delay: float = _num("land_disarm_delay", ge=0)
    velocity_hold: float = _num("velocity_hold", gt=0)
    takeover_autoland: bool = DEFAULTS["takeover_autoland"]
    takeover_land_delay: float = _num("takeover_land_delay", ge=0)
    link_loss: bool = DEFAULTS["link_loss"]
    refuse_arm: bool = DEFAULTS["refuse_arm"]
    time_scale: float = _num("time_scale", gt=0)
    max_step: float = _num("max_step", gt=0)
    link_loss_after: float = _num("link_loss_after", ge=0)
    link_loss_for: float = _num("link_loss_for", ge=0)
    takeover_after: float = _num("takeover_after", ge=0)
    failsafe_after: float = _num("failsafe_after", ge=0)
    failsafe_mode: Literal["rtl", "land", "brake"] = DEFAULTS["failsafe_mode"]
    failsafe_reason: str = DEFAULTS["failsafe_reason"]
    state_error_after: float = _num("state_error_after", ge=0)
    state_error_for: float = _num("state_error_for", ge=0)
    cells: int = Field(default=DEFAULTS["cells"], ge=0, le=14)
    voltage_sag: float = _num("voltage_sag", ge=0)
    battery_warning_at: float = _num("battery_warning_at", ge=0, le=100)
    state_file: str = DEFAULTS["state_file"]


_AUTONOMOUS_MODES = {
    "GUIDED": FlightMode.GUIDED,
    "LAND": FlightMode.LANDING,
    "RTL": FlightMode.RTL,
    "BRAKE": FlightMode.HOLD,  # ArduCopter's fence action: stop and hold
}
#: `trigger_failsafe` modes: the autopilot mode each switches to.
FAILSAFE_MODES = {"rtl": "RTL", "land": "LAND", "brake": "BRAKE"}
_CELL_FULL, _CELL_EMPTY = 4.2, 3.4  # V per cell at 100% and 0%
_HOME_RADIUS = 0.05  # m: close enough to home to start the RTL descent


def _state_of(values: dict[str, Any]) -> AutopilotState:
    """An `AutopilotState` holding ``values`` (every field, ``flight_mode`` given), built without the
    frozen dataclass's ``__init__``: its per-field ``object.__setattr__`` took two thirds of a
    snapshot, and the sim makes 20 a second per agent. Equal to ``AutopilotState(**values)``
    (tests/vehicles/test_sim_autopilot.py checks it)."""
    state = _new(AutopilotState)
    state.__dict__.update(values)
    return state


_new = object.__new__


class _Motion(enum.Enum):
    """What the kinematic model is doing (the Tello adapter's `_Phase` is a different thing: its mode)."""

    GROUND = "ground"
    CLIMB = "climb"  # takeoff
    GUIDED = "guided"  # following velocity set-points (hover without)
    RETURN = "return"  # RTL leg home
    DESCEND = "descend"  # LAND, end of RTL, or the pilot landing
    PILOT = "pilot"  # a pilot holds the vehicle
    HOLD = "hold"  # the autopilot brakes and holds position (failsafe BRAKE)


# The members bound once: in CPython 3.11 reading ``_Motion.GROUND`` calls the enum's descriptor
# (~125 ns, an attribute read ~10), and each poll of a thousand sims compares a few of them.
_M_GROUND, _M_CLIMB, _M_GUIDED, _M_RETURN = _Motion.GROUND, _Motion.CLIMB, _Motion.GUIDED, _Motion.RETURN
_M_DESCEND, _M_PILOT, _M_HOLD = _Motion.DESCEND, _Motion.PILOT, _Motion.HOLD
_MANUAL, _BODY = FlightMode.MANUAL, Frame.BODY


class SimAutopilot(Autopilot):
    """A kinematic quadcopter; see the module docstring for the model and the fault injection."""

    name = "sim"
    blocking = False  # in-process: every command returns at once
    params_model = Params
    # Slots: an instance with more than 30 attributes in its __dict__ loses CPython's shared-key
    # dict (3.11: every attribute read a hash lookup in a 1.6 KB table of its own); a thousand
    # sims are polled 20 times a second each. Subclasses and the base's attributes keep a __dict__.
    __slots__ = (
        "_p",
        "home",
        "_tau",
        "_time_scale",
        "_max_step",
        "_velocity_hold",
        "_max_speed",
        "_climb_rate",
        "_descent_rate",
        "_max_yaw_rate",
        "north",
        "east",
        "alt",
        "vn",
        "ve",
        "vd",
        "heading",
        "battery",
        "armed",
        "in_air",
        "mode",
        "_phase",
        "_takeoff_alt",
        "_cmd",
        "_cmd_time",
        "_armed_since",
        "_disarm_at",
        "_takeover_time",
        "_pilot_autoland",
        "_sim_time",
        "_t_last",
        "_connected",
        "_refuse_arm",
        "_link_lost_at",
        "_frozen",
        "_airborne_since",
        "_fired",
        "_ends",
        "_battery_params",
        "_scheduled",
        "_failsafe",
        "_state_error",
        "_state_file",
        "_saved_at",
        "_drain",
        "_latlon_of",
        "_latlon",
    )

    def __init__(self, params: Mapping[str, Any] | None = None, *, clock: Clock = time.monotonic) -> None:
        super().__init__(params, clock=clock)
        self.validate_params(self.params)  # ValueError naming the key, as at config load
        p = {**DEFAULTS, **self.params}
        self._p = p
        for key in (
            "link_loss_for",
            "failsafe_after",
            "state_error_after",
            "state_error_for",
            "voltage_sag",
            "battery_warning_at",
        ):
            if not (math.isfinite(float(p[key])) and float(p[key]) >= 0.0):
                raise ValueError(f"sim autopilot parameter {key!r} must be >= 0, got {p[key]!r}")
        if str(p["failsafe_mode"]) not in FAILSAFE_MODES:
            raise ValueError(
                f"sim autopilot parameter 'failsafe_mode' must be one of {sorted(FAILSAFE_MODES)},"
                f" got {p['failsafe_mode']!r}"
            )
        if not (isinstance(p["cells"], int) and 0 <= p["cells"] <= 14):
            raise ValueError(
                f"sim autopilot parameter 'cells' must be an integer in [0, 14], got {p['cells']!r}"
            )
        self.home = FlatFrame(float(p["home_lat"]), float(p["home_lon"]))
        self._tau = float(p["tau"])
        self._time_scale = float(p["time_scale"])
        self._max_step = float(p["max_step"])
        #: Read by every step of flight (the parameters never change after construction).
        self._velocity_hold = float(p["velocity_hold"])
        self._max_speed = float(p["max_speed"])
        self._climb_rate = float(p["climb_rate"])
        self._descent_rate = float(p["descent_rate"])
        self._max_yaw_rate = float(p["max_yaw_rate"])
        # Vehicle state (local frame: metres north/east of home, altitude above home).
        self.north = 0.0
        self.east = 0.0
        self.alt = 0.0
        self.vn = 0.0
        self.ve = 0.0
        self.vd = 0.0
        self.heading = wrap_360(float(p["heading"]))
        self.battery = self._check_battery(float(p["battery"]))
        self.armed = False
        self.in_air = False
        self.mode = "GUIDED"
        self._phase = _M_GROUND
        self._takeoff_alt = 0.0
        self._cmd: tuple[float, float, float, float, Frame] | None = None  # vx, vy, vz, yaw_rate, frame
        self._cmd_time = 0.0
        self._armed_since: float | None = None  # sim time the vehicle was armed on the ground
        self._disarm_at: float | None = None  # sim time of a pending post-landing disarm
        self._takeover_time = 0.0
        self._pilot_autoland = bool(p["takeover_autoland"])
        # Time and link.
        self._sim_time = 0.0
        self._t_last = clock()
        self._connected = False
        self._refuse_arm = bool(p["refuse_arm"])
        self._link_lost_at: float | None = None
        self._frozen: AutopilotState | None = None
        self._airborne_since: float | None = None
        self._fired: set[str] = set()
        self._ends: dict[str, float] = {}  # scheduled fault -> sim time it ends
        #: Whether any fault is scheduled at all (state() runs 20 times a second per simulated agent).
        #: cells, voltage sag per cell in the air, warning level (%): read by every snapshot.
        self._battery_params = (
            int(self._p["cells"]),
            float(self._p["voltage_sag"]),
            float(self._p["battery_warning_at"]),
        )
        self._scheduled = any(float(self._p[name]) > 0.0 for name in _SCHEDULED_FAULTS)
        self._failsafe = ""  # the active failsafe's reason
        self._state_error: str | None = None
        self._state_file = str(p["state_file"])
        self._saved_at = 0.0
        #: %/min drained on the ground and in the air (indexed by `in_air`: read every step).
        self._drain = (float(p["drain_idle"]), float(p["drain_flying"]))
        self._latlon_of: tuple[float, float] | None = None  # (north, east) of `_latlon`
        self._latlon = (0.0, 0.0)
        if p["link_loss"]:
            self._link_lost_at = self._t_last
            self._frozen = AutopilotState(connected=True, link_age=math.inf)

    # ----------------------------------------------------------------- Autopilot contract

    def connect(self) -> None:
        if self._state_file:
            self._restore()
        self._advance()
        self._connected = True

    def close(self) -> None:
        self._connected = False

    def arm(self) -> bool:
        self._command("arm")
        if self._refuse_arm or self.battery <= 0.0:
            return False
        if not self.armed:
            self.mode = "GUIDED"
            self._failsafe = ""
            self.armed = True
            self._armed_since = self._sim_time
            self._disarm_at = None
        return True

    def disarm(self) -> None:
        self._command("disarm")
        if self.in_air:
            raise AutopilotError("disarm refused: vehicle in the air")
        self._disarm()

    def takeoff(self, alt: float) -> None:
        self._command("takeoff")
        check_takeoff_altitude(alt)
        if not self.armed:
            raise AutopilotError("takeoff refused: not armed")
        if self.mode != "GUIDED":
            raise AutopilotError(f"takeoff refused: mode {self.mode}, needs GUIDED")
        if self.in_air:
            raise AutopilotError("takeoff refused: already flying")
        self.in_air = True
        self._takeoff_alt = alt
        self._armed_since = None
        self._airborne_since = self._sim_time
        self._phase = _M_CLIMB

    def land(self) -> None:
        self._command("land")
        self.mode = "LAND"
        self._failsafe = ""
        self._cmd = None
        if self.in_air:
            self._phase = _M_DESCEND
        elif self.armed:
            self._disarm()

    def rtl(self) -> None:
        self._command("rtl")
        self.mode = "RTL"
        self._failsafe = ""
        self._cmd = None
        if self.in_air:
            self._phase = _M_RETURN
        elif self.armed:
            self._disarm()

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        self._command("set_velocity")
        check_velocity(vx, vy, vz, yaw_rate)
        if self.mode != "GUIDED" or self._phase is not _M_GUIDED:
            return  # like ArduCopter: velocity targets are ignored outside GUIDED flight
        self._cmd = (vx, vy, vz, yaw_rate, Frame(frame))
        self._cmd_time = self._sim_time

    def state(self) -> AutopilotState:
        self._advance()
        if self._ends or self._scheduled:  # most sims schedule no fault: no call 20 times a second
            self._scheduled_faults()
        if self._state_file and self._connected:
            self._persist()
        if self._state_error is not None:
            raise RuntimeError(self._state_error)
        if not self._connected:
            return AutopilotState(connected=False, link_age=math.inf)
        if self._link_lost_at is not None:
            frozen = self._frozen if self._frozen is not None else self._snapshot()
            if math.isinf(frozen.link_age):
                return frozen  # never heard from at all
            return replace(frozen, link_age=max(0.0, self.clock() - self._link_lost_at))
        return self._snapshot()

    # ----------------------------------------------------------------- fault injection

    def set_link_loss(self, lost: bool) -> None:
        """Stop (or resume) answering. The vehicle keeps flying either way."""
        self._advance()
        if lost and self._link_lost_at is None:
            self._frozen = self._snapshot() if self._connected else AutopilotState(connected=True)
            self._link_lost_at = self.clock()
        elif not lost:
            self._link_lost_at = None
            self._frozen = None

    def trigger_failsafe(self, mode: str = "rtl", reason: str = "fence breach") -> None:
        """The autopilot's own failsafe takes over: ``rtl``, ``land`` or ``brake`` (hold position)."""
        if mode not in FAILSAFE_MODES:
            raise ValueError(f"failsafe mode must be one of {sorted(FAILSAFE_MODES)}, got {mode!r}")
        self._advance()
        self.mode = FAILSAFE_MODES[mode]
        self._failsafe = reason or mode
        self._cmd = None
        if self.in_air:
            self._phase = {"rtl": _M_RETURN, "land": _M_DESCEND, "brake": _M_HOLD}[mode]
        elif self.armed:
            self._disarm()

    def set_state_error(self, text: str | None) -> None:
        """Make `state()` raise ``RuntimeError(text)`` (None: stop). The vehicle flies on."""
        self._state_error = text

    def set_refuse_arm(self, refuse: bool) -> None:
        self._refuse_arm = refuse

    def set_battery(self, percent: float) -> None:
        self._advance()
        self.battery = self._check_battery(percent)

    def set_time_scale(self, scale: float) -> None:
        if not (math.isfinite(scale) and scale > 0.0):
            raise ValueError(f"time_scale must be > 0, got {scale!r}")
        self._advance()  # time so far runs at the old scale
        self._time_scale = scale

    def pilot_takeover(self, auto_land: bool | None = None) -> None:
        """A pilot flips the mode switch: LOITER, no longer autonomous; optionally lands after a delay."""
        self._advance()
        self.mode = "LOITER"
        self._failsafe = ""
        self._cmd = None
        if auto_land is not None:
            self._pilot_autoland = auto_land
        if self.in_air:
            self._phase = _M_PILOT
            self._takeover_time = self._sim_time

    def _scheduled_faults(self) -> None:
        p = self._p
        if self._ends:
            for name, end in list(self._ends.items()):
                if self._sim_time >= end:
                    del self._ends[name]
                    if name == "link_loss_after":
                        self.set_link_loss(False)
                    else:
                        self.set_state_error(None)
        if not self._scheduled or self._airborne_since is None or not self.in_air:
            return
        flown = self._sim_time - self._airborne_since
        faults: tuple[tuple[str, Callable[[], None], float], ...] = (
            ("takeover_after", self.pilot_takeover, 0.0),
            ("link_loss_after", lambda: self.set_link_loss(True), float(p["link_loss_for"])),
            (
                "failsafe_after",
                lambda: self.trigger_failsafe(str(p["failsafe_mode"]), str(p["failsafe_reason"])),
                0.0,
            ),
            (
                "state_error_after",
                lambda: self.set_state_error("simulated adapter fault: state() failed"),
                float(p["state_error_for"]),
            ),
        )
        for name, fire, lasts in faults:
            after = float(p[name])
            if after > 0.0 and flown >= after and name not in self._fired:
                self._fired.add(name)
                fire()
                if lasts > 0.0:
                    self._ends[name] = self._sim_time + lasts

    # ----------------------------------------------------------------- persistence across restarts

    _PERSISTED = (
        "north",
        "east",
        "alt",
        "vn",
        "ve",
        "vd",
        "heading",
        "battery",
        "armed",
        "in_air",
        "mode",
        "_takeoff_alt",
        "_failsafe",
    )

    def _persist(self) -> None:
        wall = time.time()
        if wall - self._saved_at < 0.2:
            return
        self._saved_at = wall
        data = {k: getattr(self, k) for k in self._PERSISTED}
        data["phase"] = self._phase.name
        data["saved_at"] = wall
        tmp = f"{self._state_file}.tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(data, f)
        os.replace(tmp, self._state_file)

    def _restore(self) -> None:
        try:
            with open(self._state_file, encoding="utf-8") as f:
                data = json.load(f)
        except FileNotFoundError:
            return
        except (OSError, ValueError):
            return  # unreadable: start on the ground, as a vehicle that was never flown
        gap = time.time() - float(data.get("saved_at", 0.0))
        if not 0.0 <= gap <= 60.0:
            return
        for k in self._PERSISTED:
            if k in data:
                setattr(self, k, data[k])
        self._phase = _Motion[data.get("phase", "GROUND")]
        if self.in_air:
            self._airborne_since = self._sim_time
        # The vehicle flew on while nobody was listening.
        self._t_last = self.clock() - gap / self._time_scale

    # ----------------------------------------------------------------- helpers

    @property
    def sim_time(self) -> float:
        """Simulated seconds since construction."""
        return self._sim_time

    @staticmethod
    def _check_battery(percent: float) -> float:
        if not (math.isfinite(percent) and 0.0 <= percent <= 100.0):
            raise ValueError(f"battery must be in [0, 100] percent, got {percent!r}")
        return percent

    def _command(self, what: str) -> None:
        self._advance()
        if not self._connected:
            raise AutopilotError(f"{what}: not connected")
        if self._link_lost_at is not None:
            raise AutopilotError(f"{what}: no response from the vehicle (link lost)")

    def _disarm(self) -> None:
        self.armed = False
        self._armed_since = None
        self._disarm_at = None

    def _snapshot(self) -> AutopilotState:
        # 20 snapshots a second per simulated agent: lat/lon are recomputed only when the vehicle
        # moved, and the state is built by `_state_of` (below).
        ne = (self.north, self.east)
        if ne != self._latlon_of:
            self._latlon_of = ne
            self._latlon = self.home.to_latlon(self.north, self.east)
        lat, lon = self._latlon
        mode = self.mode
        flight_mode = _AUTONOMOUS_MODES.get(mode, _MANUAL)
        cells, sag, warn_at = self._battery_params
        battery = self.battery
        voltage = math.nan
        if cells:
            if not self.in_air:
                sag = 0.0
            voltage = cells * (_CELL_EMPTY + (_CELL_FULL - _CELL_EMPTY) * battery / 100.0 - sag)
        warning = f"battery low ({battery:.0f}% <= {warn_at:g}%)" if warn_at and battery <= warn_at else ""
        return _state_of(
            {
                "connected": True,
                "link_age": 0.0,
                "lat": lat,
                "lon": lon,
                "alt": self.alt,
                "heading": self.heading,
                "vn": self.vn,
                "ve": self.ve,
                "vd": self.vd,
                "battery": battery,
                "armed": self.armed,
                "in_air": self.in_air,
                "autonomous": flight_mode is not _MANUAL,
                "mode": mode,
                "flight_mode": flight_mode,
                "failsafe": self._failsafe,
                "voltage": voltage,
                "cells": cells,
                "battery_warning": warning,
            }
        )

    # ----------------------------------------------------------------- integration

    def _advance(self) -> None:
        now = self.clock()
        dt = max(0.0, now - self._t_last) * self._time_scale
        self._t_last = now
        if dt <= 0.0:
            return
        phase = self._phase
        if phase is _M_GROUND and self._armed_since is None and self._disarm_at is None and not self.in_air:
            # Disarmed on the ground (20 polls a second, most of a swarm's life): `_step`'s work
            # there is the battery's idle drain and nothing moving.
            self._sim_time += dt
            self.battery = max(0.0, self.battery - self._drain[False] * dt / 60.0)
            self.vn = self.ve = self.vd = 0.0
            return
        if phase is _M_GROUND or (phase is _M_GUIDED and self._one_step(dt)):
            # Nothing moves, or the set-point is followed exactly in one step (`_lag`): the HLC
            # polls at 20 Hz, a period just over ``max_step``, which cut each poll in two steps.
            self._step(dt)
            return
        while dt > 0.0:
            if self._phase is _M_GROUND:
                self._step(dt)  # nothing moves: one step, however long
                return
            h = min(dt, self._max_step)
            self._step(h)
            dt -= h

    def _one_step(self, dt: float) -> bool:
        """Whether ``dt`` s of GUIDED flight integrate in one step to what steps of ``max_step`` give.

        The lag is exact for a set-point held over the step (`_lag`), so steps differ only where a
        discrete event falls inside ``dt``: the set-point expiring (``velocity_hold``, tested at each
        step's end), the battery running out, or a touchdown (the altitude clamped at 0). When none
        can, the steps' sum is the one step (to rounding). A body-frame set-point that yaws turns
        its north/east target during the step: that one keeps the steps.
        """
        cmd = self._cmd
        if cmd is not None and self._sim_time - self._cmd_time <= self._velocity_hold:
            if self._sim_time + dt - self._cmd_time > self._velocity_hold:
                return False
            if cmd[4] is _BODY and cmd[3]:
                return False  # a body-frame set-point turning with the heading: not constant in NE

        if self.battery - self._drain[self.in_air] * dt / 60.0 <= 0.0:
            return False
        # The lag never descends faster than the faster of the current and the largest target rate.
        return self.alt > max(self.vd, self._descent_rate) * dt

    def _step(self, h: float) -> None:
        p = self._p
        self._sim_time += h
        t = self._sim_time
        drain = self._drain[self.in_air]
        self.battery = max(0.0, self.battery - drain * h / 60.0)
        if self.in_air and self.battery <= 0.0 and self._phase is not _M_DESCEND:
            self.mode = "LAND"  # the autopilot's own empty-battery failsafe
            self._failsafe = "battery empty"
            self._cmd = None
            self._phase = _M_DESCEND

        phase = self._phase
        if phase is _M_GROUND:
            self.vn = self.ve = self.vd = 0.0
            if self._armed_since is not None or self._disarm_at is not None:
                landed_long_enough = self._disarm_at is not None and t >= self._disarm_at
                idle_too_long = self._armed_since is not None and t - self._armed_since >= float(
                    p["auto_disarm_delay"]
                )
                if landed_long_enough or idle_too_long:
                    self._disarm()
        elif phase is _M_CLIMB:
            self._brake(h)
            self._vertical_to(self._takeoff_alt, float(p["climb_rate"]), h)
            if self.alt >= self._takeoff_alt:
                self._phase = _M_GUIDED
        elif phase is _M_GUIDED:
            self._follow_setpoint(h)
        elif phase is _M_RETURN:
            self._return_home(h)
        elif phase is _M_DESCEND:
            self._brake(h)
            self._vertical_to(0.0, float(p["descent_rate"]), h)
        elif phase is _M_HOLD:
            self._brake(h)
            self.vd = 0.0
        elif phase is _M_PILOT:
            self._brake(h)
            self.vd = 0.0
            if self._pilot_autoland and t - self._takeover_time >= float(p["takeover_land_delay"]):
                self._phase = _M_DESCEND
        if self.in_air and self.alt <= 0.0 and self._phase is not _M_CLIMB:
            self._touchdown()

    def _lag(self, v0: float, target: float, h: float) -> tuple[float, float]:
        """Velocity after `h` s and distance covered, following `target` with the time constant.

        Exact for a set-point held constant over the step, so results do not depend on the step size.
        """
        decay = math.exp(-h / self._tau)
        v1 = target + (v0 - target) * decay
        return v1, target * h + (v0 - target) * self._tau * (1.0 - decay)

    def _brake(self, h: float) -> None:
        self.vn, dn = self._lag(self.vn, 0.0, h)
        self.ve, de = self._lag(self.ve, 0.0, h)
        self.north += dn
        self.east += de

    def _vertical_to(self, target_alt: float, rate: float, h: float) -> None:
        """Move altitude toward `target_alt` at `rate`, stopping exactly on it."""
        gap = target_alt - self.alt
        step = min(abs(gap), rate * h)
        self.alt += math.copysign(step, gap)
        self.vd = -math.copysign(rate, gap) if step < abs(gap) else 0.0

    def _follow_setpoint(self, h: float) -> None:
        tn = te = td = 0.0
        yaw_rate = 0.0
        cmd = self._cmd
        if cmd is not None and self._sim_time - self._cmd_time <= self._velocity_hold:
            vx, vy, vz, yaw_rate, frame = cmd
            if frame is _BODY:
                tn, te = body_to_ne(vx, vy, self.heading)
            else:
                tn, te = vx, vy
            td = vz
            speed = math.hypot(tn, te)
            max_speed = self._max_speed
            if speed > max_speed:
                tn, te = tn * max_speed / speed, te * max_speed / speed
            td = max(-self._climb_rate, min(self._descent_rate, td))
            max_yaw = self._max_yaw_rate
            yaw_rate = max(-max_yaw, min(max_yaw, yaw_rate))
        # `_lag` inlined for the three axes (one exponential: the same time constant).
        decay = math.exp(-h / self._tau)
        keep = self._tau * (1.0 - decay)
        vn, ve, vd = self.vn, self.ve, self.vd
        self.vn = tn + (vn - tn) * decay
        self.ve = te + (ve - te) * decay
        self.vd = td + (vd - td) * decay
        self.north += tn * h + (vn - tn) * keep
        self.east += te * h + (ve - te) * keep
        self.alt = max(0.0, self.alt - (td * h + (vd - td) * keep))
        if yaw_rate:
            self.heading = wrap_360(self.heading + yaw_rate * h)

    def _return_home(self, h: float) -> None:
        p = self._p
        rtl_alt = float(p["rtl_altitude"])
        if self.alt < rtl_alt:
            self.vn = self.ve = 0.0
            self._vertical_to(rtl_alt, float(p["climb_rate"]), h)
            return
        self.vd = 0.0
        dist = math.hypot(self.north, self.east)
        speed = float(p["rtl_speed"])
        if dist <= max(_HOME_RADIUS, speed * h):
            # Arrive exactly (within one step's travel), stop, and descend.
            self.north = self.east = 0.0
            self.vn = self.ve = 0.0
            self._phase = _M_DESCEND
            return
        self.vn, self.ve = -self.north / dist * speed, -self.east / dist * speed
        self.north += self.vn * h
        self.east += self.ve * h
        self.heading = wrap_360(math.degrees(math.atan2(self.ve, self.vn)))

    def _touchdown(self) -> None:
        self.alt = 0.0
        self.vn = self.ve = self.vd = 0.0
        self.in_air = False
        self._phase = _M_GROUND
        self._failsafe = ""
        self._cmd = None
        if self.armed:
            if self.mode == "GUIDED":
                self._armed_since = self._sim_time  # ArduCopter: disarm if left idle on the ground
            else:
                self._disarm_at = self._sim_time + float(self._p["land_disarm_delay"])
