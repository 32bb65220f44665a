"""The Tello adapter's arithmetic, apart from its I/O so that each rule has plain unit tests.

Frames: the Tello's *ground frame* is fixed at power-on, x along the heading it faced then (its yaw
0), y 90 degrees clockwise from x (to the right). ``home_heading`` is that yaw-0 direction as a
compass heading, so a ground-frame vector rotates into north/east by ``home_heading``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from antalate_lcm.base.geo import body_to_ne
from antalate_lcm.vehicles.base import altitude_reached

RC = tuple[int, int, int, int]


def ground_to_ne(gx: float, gy: float, home_heading: float) -> tuple[float, float]:
    """A ground-frame vector (x along yaw 0, y to its right) as north/east."""
    return body_to_ne(gx, gy, home_heading)


def body_to_ground(fwd: float, right: float, yaw: float) -> tuple[float, float]:
    """A body-frame vector (forward, right) at `yaw` degrees into the ground frame."""
    return body_to_ne(fwd, right, yaw)


def ne_to_body(vn: float, ve: float, heading: float) -> tuple[float, float]:
    """A north/east vector as forward/right of a vehicle facing `heading` (compass degrees)."""
    return body_to_ne(vn, ve, -heading)


def dead_reckon(
    north: float, east: float, v0: tuple[float, float], v1: tuple[float, float], dt: float
) -> tuple[float, float]:
    """One trapezoid step of the position from the velocities at both ends of `dt` seconds.

    Negative or absurd gaps (a clock step, a link loss of minutes) integrate nothing: the velocity
    at both ends says nothing about what happened in between.
    """
    if not (0.0 < dt <= _MAX_DR_GAP):
        return north, east
    return north + 0.5 * (v0[0] + v1[0]) * dt, east + 0.5 * (v0[1] + v1[1]) * dt


_MAX_DR_GAP = 1.0  # s: state comes at 10 Hz; a longer gap is a link loss, not a step to integrate


def rc_sticks(
    fwd: float,
    right: float,
    up: float,
    yaw_rate: float,
    *,
    max_speed: float,
    max_vertical_speed: float,
    max_yaw_rate: float,
) -> RC:
    """Body-frame m/s (and deg/s) to ``rc`` sticks (left/right, forward/back, up/down, yaw).

    The horizontal pair is scaled down together when either exceeds full stick, so the direction
    of travel is kept; the other channels are clamped on their own.
    """
    lr = right / max_speed * 100.0
    fb = fwd / max_speed * 100.0
    biggest = max(abs(lr), abs(fb))
    if biggest > 100.0:
        lr, fb = lr * 100.0 / biggest, fb * 100.0 / biggest

    def stick(value: float) -> int:
        return int(round(max(-100.0, min(100.0, value))))

    return (
        stick(lr),
        stick(fb),
        stick(up / max_vertical_speed * 100.0),
        stick(yaw_rate / max_yaw_rate * 100.0),
    )


#: The climb is over inside [target, target + CLIMB_BAND]: at or above the target, so the HLC's
#: `altitude_reached` holds for any ``airborne_fraction``, and the band is one decimetre wide so a
#: decimetre reading always has a value inside it.
CLIMB_BAND = 0.1
CLIMB_GAIN = 1.5  # 1/s: vertical speed per metre of remaining climb
MIN_CLIMB_SPEED = 0.2  # m/s: so the last centimetres do not take forever


def climb_done(height: float, target: float) -> bool:
    """The rc climb to `target` is over: the reading meets the HLC's rule at fraction 1, no higher than the band."""
    return altitude_reached(height, target, 1.0) and height <= target + CLIMB_BAND + 1e-6


def climb_speed(height: float, target: float, max_vertical_speed: float) -> float:
    """Vertical speed (m/s, up positive) towards the band; 0 inside it.

    Aims at the middle of the band, so a reading a decimetre short of the target still asks for a
    climb of ``MIN_CLIMB_SPEED`` at least: the controller does not stall below the band.
    """
    if climb_done(height, target):
        return 0.0
    error = target + CLIMB_BAND / 2.0 - height
    speed = max(MIN_CLIMB_SPEED, min(max_vertical_speed, CLIMB_GAIN * abs(error)))
    return math.copysign(speed, error)


@dataclass
class Debounced:
    """A boolean from noisy samples that changes once the new value held `hold` seconds.

    The Tello's in-air flag comes from a height in whole decimetres: a single zero can be a hover at
    4 cm or one odd packet. A landing (or take-off) nobody commanded is believed once it lasted.
    """

    hold: float
    value: bool = False
    _since: float | None = None

    def update(self, sample: bool, now: float) -> bool:
        """Feed one sample; True when the confirmed `value` flipped with it."""
        if sample == self.value:
            self._since = None
            return False
        if self._since is None:
            self._since = now
        if now - self._since >= self.hold:
            self.value = sample
            self._since = None
            return True
        return False

    def reset(self, value: bool) -> None:
        self.value = value
        self._since = None


def rtl_leg(
    north: float, east: float, home: tuple[float, float], *, speed: float, gain: float, min_speed: float
) -> tuple[float, float, float]:
    """North/east velocity towards `home` and the distance left: slows down over the last metre."""
    dn, de = home[0] - north, home[1] - east
    dist = math.hypot(dn, de)
    if dist < 1e-9:
        return 0.0, 0.0, 0.0
    v = max(min_speed, min(speed, gain * dist))
    return dn / dist * v, de / dist * v, dist


_VGZ_SILENT = 0.05  # |ratio| below this: vgz was not reported at all (no unit to check)

#: m/s: a DJI Tello's top speed (its specification: 8 m/s); a ground speed read above it is a unit error.
MAX_PLAUSIBLE_SPEED = 8.0


@dataclass
class VelocityUnitCheck:
    """Checks at run time the one assumption dead reckoning rests on: the state's velocities are dm/s.

    The SDK guides name ``vgx/vgy/vgz`` without a unit. ``vgz`` is reported with them and, assumed in
    the same unit, integrates to the climb that the height (``h`` or ``tof``, in metres by the SDK)
    measures on its own: every take-off climbs 0.8 m, enough to tell decimetres from centimetres or
    metres per second (a factor of ten) through the decimetre rounding of both. A ratio outside
    [`low`, `high`] over a climb or descent of `min_change` m, or a ground speed above a Tello's
    top speed, is a `problem`; it stays (a unit does not change in flight). A ratio beyond
    [1/`far`, `far`] is a problem at once (a wrong unit is off by ten: the take-off's own 0.8 m
    climb shows it); one merely outside [`low`, `high`] must be so in `strikes` comparisons in a row:
    a single comparison over a fast take-off or landing, seen in a handful of 10 Hz packets with both
    fields rounded to decimetres, once fell outside that range with the right unit.
    """

    min_change: float = 0.5  # m of height change that makes a comparison
    max_window: float = 10.0  # s: a slower change is drift, not a comparison
    low: float = 0.5
    high: float = 2.0
    problem: str = ""
    #: set when a climb passed with ``vgz`` reading zero throughout: a Tello that does not report it
    #: cannot be checked (that is no evidence of a wrong unit, so it is not a `problem`)
    unchecked: str = ""
    ratio: float = math.nan  # the last comparison's integrated/measured change
    strikes: int = 2
    far: float = 5.0
    _out: int = 0  # comparisons out of range in a row
    _anchor: float | None = None  # the height the comparison started from
    _anchor_t: float = 0.0
    _integral: float = 0.0  # m climbed according to vgz since the anchor
    _last: tuple[float, float] | None = None  # (t, climb rate m/s) of the previous sample

    def update(self, height: float, vd: float, vn: float, ve: float, now: float) -> bool:
        """Feed one packet (m, m/s down, m/s north/east as read); True when a `problem` is first found
        (or the unit first found `unchecked`)."""
        if self.problem:
            return False
        speed = math.hypot(vn, ve)
        if speed > MAX_PLAUSIBLE_SPEED:
            self.problem = (
                f"the state's vgx/vgy read as {speed:.1f} m/s, beyond a Tello's {MAX_PLAUSIBLE_SPEED:g} m/s: "
                "they are not in the dm/s dead reckoning assumes"
            )
            return True
        last, self._last = self._last, (now, -vd)
        if last is None or not 0.0 < now - last[0] <= _MAX_DR_GAP or self._anchor is None:
            self._restart(height, now)
            return False
        self._integral += 0.5 * (last[1] - vd) * (now - last[0])
        change = height - self._anchor
        if now - self._anchor_t > self.max_window:
            self._restart(height, now)
        elif abs(change) >= self.min_change:
            self.ratio = self._integral / change
            self._restart(height, now)
            if abs(self.ratio) < _VGZ_SILENT:
                first = not self.unchecked
                self.unchecked = (
                    f"vgz read 0 while the height changed {change:+.2f} m: the unit is not checked"
                )
                return first
            elif self.low <= abs(self.ratio) <= self.high:
                self._out = 0
            else:
                self._out += 1
                if self._out < self.strikes and 1.0 / self.far <= abs(self.ratio) <= self.far:
                    return False
                self.problem = (
                    f"the state's vgz integrates to {self.ratio * change:+.2f} m while the height changed "
                    f"{change:+.2f} m (x{abs(self.ratio):.2g}): its velocities are not in the dm/s dead "
                    "reckoning assumes"
                )
                return True
        return False

    def _restart(self, height: float, now: float) -> None:
        self._anchor, self._anchor_t, self._integral = height, now, 0.0
