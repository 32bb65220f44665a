"""`FaultInjection`: the faults a real vehicle springs on the HLC, on demand or on a schedule.

For testing the HLC against faults that are hard to provoke on real hardware. Params at
construction, and methods at run time:

``link_loss`` / `set_link_loss`: the vehicle stops answering: `state()` repeats the last snapshot
with a growing ``link_age`` and commands raise `AutopilotError` (the vehicle itself flies on).
``refuse_arm`` / `set_refuse_arm`: `arm()` returns False. ``battery`` / `set_battery`: the level.
`pilot_takeover`: mode LOITER, not autonomous; with ``takeover_autoland`` the "pilot" lands after
``takeover_land_delay`` s. ``time_scale`` / `set_time_scale`: simulated seconds per real second.
`trigger_failsafe(mode, reason)`: the autopilot's own failsafe (fence, battery, EKF, GCS) switches to
``RTL``, ``LAND`` or ``BRAKE`` (holds position) and reports `VehicleState.failsafe` = reason until
it touches down or is commanded another mode. `set_state_error(text)`: `state()` raises
``RuntimeError(text)`` (an adapter bug) until called with None; the vehicle flies on meanwhile.

Scheduled faults, in s of simulated flight after takeoff (0 = never), for tests that run the sim in
another process: ``link_loss_after`` (lasting ``link_loss_for`` s, 0 = for good), ``takeover_after``,
``failsafe_after`` (``failsafe_mode`` rtl|land|brake, ``failsafe_reason``), ``state_error_after``
(lasting ``state_error_for`` s, 0 = for good). Each fires once per sim.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from antalate_lcm.vehicles.base import VehicleState
from antalate_lcm.vehicles.sim.params import Params
from antalate_lcm.vehicles.sim.physics import M_DESCEND, M_HOLD, M_PILOT, M_RETURN, Quadcopter
from antalate_lcm.vehicles.sim.telemetry import snapshot

__all__ = ["FAILSAFE_MODES", "FaultInjection"]

#: `trigger_failsafe` modes: the autopilot mode each switches to.
FAILSAFE_MODES = {"rtl": "RTL", "land": "LAND", "brake": "BRAKE"}
_FAILSAFE_MOTIONS = {"rtl": M_RETURN, "land": M_DESCEND, "brake": M_HOLD}


class FaultInjection(Quadcopter):
    """The vehicle's link (`connect` opens it, a fault loses it) and every fault of the module docstring."""

    __slots__ = (
        "_connected",
        "_refuse_arm",
        "_link_lost_at",
        "_frozen",
        "_state_error",
        "_scheduled",
        "_fired",
        "_ends",
    )

    def _init_state(self, p: Params, now: float) -> None:
        super()._init_state(p, now)
        self._connected = False
        self._refuse_arm = p.refuse_arm
        self._link_lost_at: float | None = None  # clock time the link was lost
        self._frozen: VehicleState | None = None  # what state() repeats while it is
        self._state_error: str | None = None
        #: Whether any fault is scheduled at all (state() runs 20 times a second per simulated agent).
        after = (p.takeover_after, p.link_loss_after, p.failsafe_after, p.state_error_after)
        self._scheduled = any(a > 0.0 for a in after)
        self._fired: set[str] = set()
        self._ends: dict[str, float] = {}  # scheduled fault -> sim time it ends
        if p.link_loss:
            self._link_lost_at = now
            self._frozen = VehicleState(connected=True, link_age=math.inf)

    def set_link_loss(self, lost: bool) -> None:
        """Stop (or resume) answering. The vehicle keeps flying either way."""
        self._advance()
        if lost and self._link_lost_at is None:
            self._frozen = snapshot(self) if self._connected else VehicleState(connected=True)
            self._link_lost_at = self.clock()
        elif not lost:
            self._link_lost_at = None
            self._frozen = None

    def trigger_failsafe(self, mode: str = "rtl", reason: str = "fence breach") -> None:
        """The autopilot's own failsafe takes over: ``rtl``, ``land`` or ``brake`` (hold position)."""
        if mode not in FAILSAFE_MODES:
            raise ValueError(f"failsafe mode must be one of {sorted(FAILSAFE_MODES)}, got {mode!r}")
        self._advance()
        self._switch_mode(FAILSAFE_MODES[mode], _FAILSAFE_MOTIONS[mode], reason or mode)

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
            self._phase = M_PILOT
            self._takeover_time = self._sim_time

    def _scheduled_faults(self) -> None:
        """End the scheduled faults whose time is up, then fire those due after this much flight."""
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
        faults: tuple[tuple[str, float, Callable[[], None], float], ...] = (
            ("takeover_after", p.takeover_after, self.pilot_takeover, 0.0),
            ("link_loss_after", p.link_loss_after, lambda: self.set_link_loss(True), p.link_loss_for),
            (
                "failsafe_after",
                p.failsafe_after,
                lambda: self.trigger_failsafe(p.failsafe_mode, p.failsafe_reason),
                0.0,
            ),
            (
                "state_error_after",
                p.state_error_after,
                lambda: self.set_state_error("simulated adapter fault: state() failed"),
                p.state_error_for,
            ),
        )
        for name, after, fire, lasts in faults:
            if after > 0.0 and flown >= after and name not in self._fired:
                self._fired.add(name)
                fire()
                if lasts > 0.0:
                    self._ends[name] = self._sim_time + lasts
