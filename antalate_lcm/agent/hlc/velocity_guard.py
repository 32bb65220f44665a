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
from antalate_lcm.wire.vocabulary import HlcState, McState, name_of


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
    vx, vy, vz, yaw_rate, frame_value = cmd.vx, cmd.vy, cmd.vz, cmd.yaw_rate, cmd.frame
    if not (hlc_state == _AIRBORNE and mc_state == _MISSION):  # mission_flight, inline
        return GuardDecision(
            _REJECT,
            None,
            f"velocity ignored: HLC {name_of(HlcState, hlc_state) or repr(hlc_state)},"
            f" MC {name_of(McState, mc_state) or repr(mc_state)}"
            " (needs HLC AIRBORNE and MC MISSION)",
        )
    if not link_age < limits.max_link_age:  # NaN is stale too
        return GuardDecision(
            _REJECT,
            None,
            f"velocity withheld: autopilot link {link_age:.1f} s old >= {limits.max_link_age:g} s",
        )
    if not (isfinite(vx) and isfinite(vy) and isfinite(vz) and isfinite(yaw_rate)):
        components = {"vx": vx, "vy": vy, "vz": vz, "yaw_rate": yaw_rate}
        bad = [f"{name}={value!r}" for name, value in components.items() if not isfinite(value)]
        return GuardDecision(_REJECT, None, f"velocity rejected: non-finite {', '.join(bad)}")
    try:
        frame = _FRAMES.get(frame_value)  # what Frame(frame_value) returns, without the enum's call
    except TypeError:  # unhashable: Frame() searches its members and refuses it
        frame = None
    if frame is None:
        try:
            frame = Frame(frame_value)
        except ValueError:
            return GuardDecision(_REJECT, None, f"velocity rejected: unknown frame {frame_value!r}")
    age = now - cmd.received_at
    if age > limits.velocity_timeout:
        return GuardDecision(
            _HOVER,
            Velocity.hover(),
            f"velocity stale: {age:.2f} s old > velocity_timeout {limits.velocity_timeout:g} s: hover",
        )

    notes: list[str] = []
    horizontal = hypot(vx, vy)
    max_horizontal = limits.max_horizontal
    if horizontal > max_horizontal:
        scale = max_horizontal / horizontal
        vx, vy = vx * scale, vy * scale
        notes.append(f"horizontal {horizontal:.2f} -> {max_horizontal:g} m/s")
    limit = limits.max_vertical
    if not -limit < vz < limit:  # inside, `_clamp` returns vz itself
        clamped = _clamp(vz, limit)
        if clamped != vz:
            notes.append(f"vertical {vz:.2f} -> {clamped:g} m/s")
        vz = clamped
    limit = limits.max_yaw_rate
    if not -limit < yaw_rate < limit:
        clamped = _clamp(yaw_rate, limit)
        if clamped != yaw_rate:
            notes.append(f"yaw rate {yaw_rate:.1f} -> {clamped:g} deg/s")
        yaw_rate = clamped
    if not notes:
        return GuardDecision(_SEND, Velocity(vx, vy, vz, yaw_rate, frame))
    return GuardDecision(
        _SEND, Velocity(vx, vy, vz, yaw_rate, frame), f"velocity clamped: {'; '.join(notes)}", clamped=True
    )


# Bound once, like _AIRBORNE: an enum member's attribute read costs a descriptor call in 3.11.
_SEND, _HOVER, _REJECT = Verdict.SEND, Verdict.HOVER, Verdict.REJECT
#: Frame's members by value (and by member: an IntEnum hashes as its value), for `check_velocity` and `VelocityGuard.passes`.
_FRAMES: dict[object, Frame] = {frame.value: frame for frame in Frame}


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
            hlc_state == _AIRBORNE
            and mc_state == _MISSION
            and link_age < limits.max_link_age
            and isfinite(vx)
            and isfinite(vy)
            and isfinite(vz)
            and isfinite(yaw_rate)
        ):
            return None
        try:
            known = _FRAMES.get(frame)
        except TypeError:
            return None
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
        if not (hlc_state == _AIRBORNE and mc_state == _MISSION):  # mission_flight, inline (20 Hz)
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
