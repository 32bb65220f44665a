"""The filter between behaviors' velocity commands and the autopilot (docs/design.md §6, last paragraph).

Behaviors are plugins: the HLC cannot trust them to be in the right state, to produce finite
numbers, to respect the vehicle's limits, or to keep talking. This module decides, for each command
and on each tick, what (if anything) goes to `VehicleAdapter.set_velocity` and why:

* a command is only passed on while the HLC is AIRBORNE **and** the MC is in MISSION (otherwise the
  autopilot is taking off, landing or returning, or a pilot flies, and must not be disturbed);
* NaN or infinite components reject the whole command (a partly-applied command is worse than none);
* the horizontal velocity is scaled down, direction preserved, to ``max_horizontal`` (the norm, so a
  diagonal is not faster than a straight line); vertical speed and yaw rate are clamped per component;
* a command whose age (now - receive time) exceeds ``velocity_timeout`` is replaced by zero velocity
  (hover); when behaviors fall silent, `VelocityGuard.tick` sends that hover once;
* nothing is sent while the autopilot link is stale: its age *at the moment of the set-point* is
  ``max_link_age`` or more (the HLC node's ``link_timeout``, its definition of a live link; not less,
  since ArduCopter's HEARTBEAT comes only once a second). The HLC notices LLC_DOWN on its 20 Hz
  control tick; this closes the gap between ticks. A set-point queued into a dead link could be
  delivered late, and a vehicle that just got its link back must not fly on a behavior's old wish.
  LLC_DOWN and HOLD are not mission flight, so nothing passes there either; the hover owed by
  `VelocityGuard.tick` waits until the link is fresh again.

Receive time, not the sender's ``header.utime``, is what ages a command: clocks of different
machines are not synchronised, the HLC's own monotonic clock is.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from math import hypot, isfinite

from antalate_lcm.vehicles.base import Frame
from antalate_lcm.wire.vocabulary import HlcState, McState, member_of, name_of


@dataclass(frozen=True)
class VelocityLimits:
    """Velocity limits and staleness (``[hlc]`` config)."""

    max_horizontal: float = 5.0  # m/s, norm of the horizontal vector
    max_vertical: float = 2.0  # m/s, up or down
    max_yaw_rate: float = 90.0  # deg/s, either way
    velocity_timeout: float = 0.5  # s after receipt before a command counts as stale
    max_link_age: float = 3.0  # s: a link this old is stale, nothing is sent (the node's link_timeout)

    def __post_init__(self) -> None:
        for name in ("max_horizontal", "max_vertical", "max_yaw_rate", "velocity_timeout", "max_link_age"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"VelocityLimits.{name} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True)
class Velocity:
    """A set-point to pass to `VehicleAdapter.set_velocity` (m/s, z down; deg/s clockwise)."""

    vx: float
    vy: float
    vz: float
    yaw_rate: float
    frame: Frame = Frame.BODY

    @classmethod
    def hover(cls) -> Velocity:
        return cls(0.0, 0.0, 0.0, 0.0, Frame.BODY)


@dataclass(frozen=True)
class VelocityCommand:
    """A velocity command as received; `received_at` is the HLC's monotonic clock at receipt."""

    vx: float
    vy: float
    vz: float
    yaw_rate: float
    frame: Frame | int
    received_at: float


class Verdict(enum.Enum):
    SEND = "SEND"  # pass `send` on (possibly clamped)
    HOVER = "HOVER"  # stale: send zero velocity
    REJECT = "REJECT"  # send nothing


@dataclass(frozen=True)
class GuardDecision:
    """What to send (None = nothing) and why; `clamped` tells the node to mention it in its log."""

    verdict: Verdict
    send: Velocity | None
    reason: str = ""
    clamped: bool = False

    @property
    def accepted(self) -> bool:
        return self.verdict is Verdict.SEND


def mission_flight(hlc_state: HlcState | int, mc_state: McState | int | None) -> bool:
    """The only situation in which behaviors may steer the vehicle."""
    return hlc_state == _AIRBORNE and mc_state == _MISSION


# Bound once: in CPython 3.11 ``HlcState.AIRBORNE`` calls the enum's descriptor (~125 ns), and the
# HLC asks `mission_flight` on every control tick (20 a second per agent).
_AIRBORNE, _MISSION = HlcState.AIRBORNE, McState.MISSION


def check_velocity(
    cmd: VelocityCommand,
    now: float,
    hlc_state: HlcState | int,
    mc_state: McState | int | None,
    limits: VelocityLimits,
    link_age: float = 0.0,
) -> GuardDecision:
    """Stateless verdict on one command (see the module docstring for the rules).

    `link_age` is the age of the autopilot's last snapshot (`VehicleState.link_age`).
    """
    if not mission_flight(hlc_state, mc_state):
        return GuardDecision(
            Verdict.REJECT,
            None,
            f"velocity ignored: HLC {name_of(HlcState, hlc_state) or repr(hlc_state)},"
            f" MC {name_of(McState, mc_state) or repr(mc_state)}"
            " (needs HLC AIRBORNE and MC MISSION)",
        )
    if not link_age < limits.max_link_age:  # NaN is stale too
        return GuardDecision(
            Verdict.REJECT,
            None,
            f"velocity withheld: autopilot link {link_age:.1f} s old >= {limits.max_link_age:g} s",
        )
    components = {"vx": cmd.vx, "vy": cmd.vy, "vz": cmd.vz, "yaw_rate": cmd.yaw_rate}
    bad = [f"{name}={value!r}" for name, value in components.items() if not math.isfinite(value)]
    if bad:
        return GuardDecision(Verdict.REJECT, None, f"velocity rejected: non-finite {', '.join(bad)}")
    try:
        frame = Frame(cmd.frame)
    except ValueError:
        return GuardDecision(Verdict.REJECT, None, f"velocity rejected: unknown frame {cmd.frame!r}")
    age = now - cmd.received_at
    if age > limits.velocity_timeout:
        return GuardDecision(
            Verdict.HOVER,
            Velocity.hover(),
            f"velocity stale: {age:.2f} s old > velocity_timeout {limits.velocity_timeout:g} s: hover",
        )

    notes: list[str] = []
    vx, vy = cmd.vx, cmd.vy
    horizontal = math.hypot(vx, vy)
    if horizontal > limits.max_horizontal:
        scale = limits.max_horizontal / horizontal
        vx, vy = vx * scale, vy * scale
        notes.append(f"horizontal {horizontal:.2f} -> {limits.max_horizontal:g} m/s")
    vz = _clamp(cmd.vz, limits.max_vertical)
    if vz != cmd.vz:
        notes.append(f"vertical {cmd.vz:.2f} -> {vz:g} m/s")
    yaw_rate = _clamp(cmd.yaw_rate, limits.max_yaw_rate)
    if yaw_rate != cmd.yaw_rate:
        notes.append(f"yaw rate {cmd.yaw_rate:.1f} -> {yaw_rate:g} deg/s")
    reason = f"velocity clamped: {'; '.join(notes)}" if notes else ""
    return GuardDecision(Verdict.SEND, Velocity(vx, vy, vz, yaw_rate, frame), reason, clamped=bool(notes))


# Bound once, like _AIRBORNE: an enum member's attribute read costs a descriptor call in 3.11.
_SEND, _HOVER, _REJECT = Verdict.SEND, Verdict.HOVER, Verdict.REJECT


def _clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


class VelocityGuard:
    """`check_velocity` plus the memory needed to hover once when commands stop arriving."""

    __slots__ = ("limits", "last_received", "_hovering")

    def __init__(self, limits: VelocityLimits | None = None) -> None:
        self.limits = limits or VelocityLimits()
        #: Receipt time of the last command passed on, None when none can go stale (read by the HLC's
        #: control tick before it calls `tick`).
        self.last_received: float | None = None
        self._hovering = False

    def on_command(
        self,
        cmd: VelocityCommand,
        now: float,
        hlc_state: HlcState | int,
        mc_state: McState | int | None,
        link_age: float = 0.0,
    ) -> GuardDecision:
        decision = check_velocity(cmd, now, hlc_state, mc_state, self.limits, link_age)
        self._note(decision, cmd.received_at, hlc_state, mc_state)
        return decision

    def passes(
        self,
        vx: float,
        vy: float,
        vz: float,
        yaw_rate: float,
        frame: Frame | int,
        now: float,
        hlc_state: HlcState | int,
        mc_state: McState | int | None,
        link_age: float,
    ) -> Frame | None:
        """The HLC's hot path for a command received ``now``: the `Frame` to send its values in when
        it passes as it came (nearly every command of a flight: no `VelocityCommand`, `Velocity` or
        decision is built), remembered as `on_command` would; None when it does not, and
        `on_command` decides (nothing remembered here then). Every check of `check_velocity` is made, the
        clamps' as "inside the limits" (a command at a limit exactly goes to `on_command`)."""
        limits = self.limits
        if not (
            mission_flight(hlc_state, mc_state)
            and link_age < limits.max_link_age
            and isfinite(vx)
            and isfinite(vy)
            and isfinite(vz)
            and isfinite(yaw_rate)
        ):
            return None
        known = member_of(Frame, frame)
        vertical, yaw = limits.max_vertical, limits.max_yaw_rate
        if (
            known is None
            or not -vertical < vz < vertical
            or not -yaw < yaw_rate < yaw
            or hypot(vx, vy) > limits.max_horizontal
            or limits.velocity_timeout < 0.0  # received now: never stale (`__post_init__` says >= 0)
        ):
            return None
        self.last_received = now
        self._hovering = False
        return known

    def _note(
        self,
        decision: GuardDecision,
        received_at: float,
        hlc_state: HlcState | int,
        mc_state: McState | int | None,
    ) -> None:
        """Remember what a command's decision means for `tick`."""
        if decision.verdict is _SEND:
            self.last_received = received_at
            self._hovering = False
        elif decision.verdict is _HOVER:
            self._hovering = True
        elif not mission_flight(hlc_state, mc_state):
            self.last_received = None  # nothing of ours is flying any more

    def tick(
        self, now: float, hlc_state: HlcState | int, mc_state: McState | int | None, link_age: float = 0.0
    ) -> GuardDecision | None:
        """Call periodically: returns a HOVER decision once after the last command went stale."""
        last = self.last_received
        if last is None:
            return None  # no command passed on since the last flight (or ever): nothing to go stale
        if not mission_flight(hlc_state, mc_state):
            self.last_received = None
            return None
        if self._hovering or not link_age < self.limits.max_link_age:
            return None
        age = now - last
        if age <= self.limits.velocity_timeout:
            return None
        self._hovering = True
        return GuardDecision(
            Verdict.HOVER,
            Velocity.hover(),
            f"no velocity command for {age:.2f} s > velocity_timeout {self.limits.velocity_timeout:g} s: hover",
        )
