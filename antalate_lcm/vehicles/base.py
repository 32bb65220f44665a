"""The vehicle adapter contract (docs/design.md §7): what the HLC needs from any vehicle, and nothing more.

The HLC is written against `VehicleAdapter` only, so a simulator, a Tello and an ArduCopter are
interchangeable by config. An adapter is a class registered under the entry-point group
``antalate.autopilots`` (see `antalate_lcm.vehicles.load_adapter`).

Constructor contract
--------------------
Every adapter is constructed as ``Cls(params, *, clock=time.monotonic)``:

* ``params`` is the ``[hlc.autopilot_params]`` table of the config as a plain ``dict`` (unknown keys should
  raise `ValueError` naming the key, so a typo does not silently fall back to a default);
  an adapter declares them as a pydantic model in `VehicleAdapter.params_model`
  (``ConfigDict(extra="forbid", strict=True)``), which `antalate_lcm.agent.plan` validates before anything
  starts, so an error names ``hlc.autopilot_params.<field>``; `VehicleAdapter.validate_params` applies the same
  rules in the constructor;
* ``clock`` is a monotonic clock in seconds. Adapters must take every timestamp from it (link age,
  dead reckoning, simulation), never from `time` directly, so tests can drive them with a fake clock.

The constructor must not do I/O; `connect()` does.

Threading contract
------------------
The HLC node calls `connect()` once, then `state()` at 10 Hz or more, and the commands (`arm`,
`takeoff`, `land`, `rtl`, `set_velocity`, `disarm`) -- all from the one executor thread of its
process. Adapters may run their own receive threads; `state()` must then return a consistent
snapshot and must not block for long (it is on the control loop). A command that the vehicle refuses
or does not acknowledge raises `AutopilotError` (except `arm()`, which returns ``False`` on a plain
refusal); the node reports it as an ``hlc_error_t`` and feeds the failure to the HLC machine.
"""

from __future__ import annotations

import enum
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

from pydantic import BaseModel

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.base.errors import AutopilotError as AutopilotError
from antalate_lcm.base.strict import validate_strict
from antalate_lcm.msgs import velocity_cmd_t

Clock = Callable[[], float]


class Frame(enum.IntEnum):
    """Reference frame of a velocity set-point; values are the ``velocity_cmd_t`` constants."""

    BODY = velocity_cmd_t.BODY  # x forward, y right, z down (heading-relative)
    NED = velocity_cmd_t.NED  # x north, y east, z down


class FlightMode(enum.Enum):
    """What the autopilot is doing, classified for the HLC (the raw mode name is in `mode`).

    The HLC needs this to resynchronise after a restart (docs/design.md §6, INIT row) and to notice that
    the autopilot or a pilot took over; it cannot interpret each vendor's mode names itself.
    """

    GUIDED = "GUIDED"  # on the ground or flying under our commands (arm, takeoff, velocity)
    LANDING = "LANDING"  # the autopilot is landing on its own logic (ArduCopter LAND)
    RTL = "RTL"  # the autopilot is returning to launch (and will land there)
    MANUAL = "MANUAL"  # a human pilot has control (LOITER, STABILIZE, ALT_HOLD, ...)
    HOLD = "HOLD"  # the autopilot holds position on its own logic (ArduCopter BRAKE on a fence breach)


@dataclass(frozen=True, slots=True)
class VehicleState:
    """One consistent snapshot of the vehicle as the adapter knows it.

    The defaults describe "nothing known yet": not connected, infinitely stale link, unknown battery;
    `autonomous` defaults to True because a vehicle without a pilot's radio (Tello, sim) is always
    under computer control.

    `autonomous` means the vehicle is under computer control (our GUIDED commands, or a LAND/RTL the
    autopilot runs itself); ``False`` means a pilot has control and the HLC must not fight them.
    `flight_mode` refines it; when an adapter leaves it out it is derived from `autonomous`
    (GUIDED or MANUAL), which is all a simple vehicle can say.

    Slotted: the HLC polls one a tick per agent (20 a second); as a ``__dict__`` each was a table
    of its own (its 19 keys, about 700 bytes out of the allocator) read by hash lookups, a thousand
    agents' snapshots out of the caches by their next tick (docs/simulator.md, "Issue 32, sixth pass").
    """

    connected: bool = False
    link_age: float = math.inf  # s since the last heartbeat/state from the vehicle
    lat: float = math.nan  # deg WGS84
    lon: float = math.nan  # deg WGS84
    alt: float = 0.0  # m above home
    heading: float = 0.0  # deg from north, clockwise, [0, 360)
    vn: float = 0.0  # m/s north
    ve: float = 0.0  # m/s east
    vd: float = 0.0  # m/s down
    battery: float = -1.0  # percent, -1 = unknown
    armed: bool = False
    in_air: bool = False
    autonomous: bool = True
    mode: str = ""  # the autopilot's own mode name, shown to people
    flight_mode: FlightMode | None = None
    #: Why the autopilot took control on its own ("fence breach", "battery failsafe", "EKF failsafe",
    #: "GCS failsafe"); empty when no failsafe is active. With `flight_mode` RTL, LANDING or HOLD it
    #: tells the HLC that the mode change was the autopilot's, not a pilot's.
    failsafe: str = ""
    voltage: float = math.nan  # battery voltage (V), NaN = unknown
    cells: int = 0  # battery cells in series, 0 = unknown (voltage per cell needs both)
    #: The vehicle's own verdict that the battery is low or critical (BATTERY_STATUS charge_state,
    #: ArduPilot's "Battery Failsafe"); empty when it has none. Any one of percentage, voltage per
    #: cell and this makes the HLC's battery low, whichever comes first.
    battery_warning: str = ""

    def __post_init__(self) -> None:
        if self.flight_mode is None:
            derived = FlightMode.GUIDED if self.autonomous else FlightMode.MANUAL
            object.__setattr__(self, "flight_mode", derived)

    @property
    def landed(self) -> bool:
        """On the ground with motors disarmed: the only state from which the HLC may be READY again."""
        return not self.in_air and not self.armed

    @property
    def battery_known(self) -> bool:
        return self.battery >= 0.0

    @property
    def cell_voltage(self) -> float:
        """Volts per cell, NaN when the voltage or the cell count is unknown."""
        if self.cells > 0 and math.isfinite(self.voltage) and self.voltage > 0.0:
            return self.voltage / self.cells
        return math.nan


#: Slack in `altitude_reached` for floating-point noise only (a height of exactly the threshold counts).
_ALTITUDE_EPSILON = 1e-6


def altitude_reached(alt: float, target: float, fraction: float) -> bool:
    """The one rule for "the take-off altitude is reached", used by the HLC and by adapters.

    The HLC counts a vehicle AIRBORNE once ``alt >= fraction * target`` (its ``airborne_fraction``,
    0.95 by default): a barometer wanders, and a vehicle that holds 95% of the altitude is flying.
    An adapter that climbs to the target itself (the Tello's rc climb) must not stop earlier than the
    HLC demands, so it stops on this same test of its *reading* with ``fraction = 1`` (the strictest
    value the HLC can be configured to), never on "within the sensor's resolution of the target":
    a Tello reports its height in whole decimetres, so "within 0.1 m of 1.2 m" stops at a reading of
    1.1 m, below the HLC's 1.14 m, and the HLC's GAIN_ALTITUDE_TIMEOUT lands it. A coarse sensor's
    reading only moves in steps, so an adapter keeps climbing until the reading itself crosses the
    threshold; the only tolerance here is for floating-point noise (``0.95 * 1.2`` is 1.1399999...).
    """
    return alt >= fraction * target - _ALTITUDE_EPSILON


def check_takeoff_altitude(alt: float) -> None:
    """The argument check every adapter's ``takeoff`` starts with: no vehicle is sent NaN or a height <= 0."""
    if not (math.isfinite(alt) and alt > 0.0):
        raise AutopilotError(f"takeoff refused: altitude {alt!r} must be > 0")


def check_velocity(vx: float, vy: float, vz: float, yaw_rate: float) -> None:
    """The argument check every adapter's ``set_velocity`` starts with: no vehicle is sent inf or NaN."""
    values = (vx, vy, vz, yaw_rate)
    if not all(math.isfinite(v) for v in values):
        raise AutopilotError(f"velocity refused: non-finite value in {values}")


class VehicleAdapter(ABC):
    """Base class of every vehicle adapter (see the module docstring for the call contract)."""

    #: Registry name, also published in ``hlc_state_t.autopilot``.
    name: ClassVar[str] = ""
    #: Whether commands may block (waiting for acknowledgements over a radio link). The HLC node
    #: then runs them on a worker thread of its own, so one slow vehicle never stalls the executor
    #: that every agent in the process shares. Only an in-process adapter should set it False.
    blocking: ClassVar[bool] = True
    #: The params (``[hlc.autopilot_params]`` table) as a pydantic model with ``extra="forbid"`` and
    #: ``strict=True``: validated when the config is loaded, so a typo, a wrong type or an
    #: out-of-range value stops the program naming ``hlc.autopilot_params.<field>`` before any node starts.
    #: None = the adapter checks its params in its constructor only.
    params_model: ClassVar[type[BaseModel] | None] = None
    #: Why the last `arm` returned False (e.g. ArduCopter's PreArm text), "" when the adapter cannot
    #: say: the HLC puts it into its ``hlc_error_t``. An adapter sets it before refusing.
    last_refusal: str = ""
    # No __slots__ of its own beyond this: an adapter that declares none (every one but the sim)
    # has a __dict__ as ever; the sim lists ``params`` and ``clock`` in its own (vehicles/sim).
    __slots__ = ()

    @classmethod
    def validate_params(cls, params: Mapping[str, Any] | None) -> BaseModel | None:
        """``params`` validated by `params_model` exactly as the config loader does, or None without one.

        Strict as TOML types values (`antalate_lcm.base.strict`): "5" is not a number, "yes" not a
        boolean, an int fills a float. Raises `antalate_lcm.base.strict.StrictError` (a `ValueError`)
        whose ``key`` is the field.
        """
        if cls.params_model is None:
            return None
        return validate_strict(cls.params_model, dict(params or {}))

    def __init__(self, params: Mapping[str, Any] | None = None, *, clock: Clock = time.monotonic) -> None:
        self.params: dict[str, Any] = dict(params or {})  # type: ignore[misc]  # a subclass's __dict__, or its slot
        self.clock: Clock = clock  # type: ignore[misc]

    @abstractmethod
    def connect(self) -> None:
        """Open the link to the vehicle. Raises `AutopilotError` if it cannot be opened at all."""

    @abstractmethod
    def close(self) -> None:
        """Release the link and any threads; idempotent."""

    @abstractmethod
    def arm(self) -> bool:
        """Enter the mode that accepts our commands and arm; ``False`` if the vehicle refused."""

    @abstractmethod
    def disarm(self) -> None:
        """Disarm the motors (on the ground)."""

    @abstractmethod
    def takeoff(self, alt: float) -> None:
        """Climb to `alt` metres above home and hold there."""

    @abstractmethod
    def land(self) -> None:
        """Land where the vehicle is, then disarm."""

    @abstractmethod
    def rtl(self) -> None:
        """Return to the launch point and land there."""

    @abstractmethod
    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        """Velocity set-point in m/s (z down) and yaw rate in deg/s (clockwise), in `frame`."""

    @abstractmethod
    def state(self) -> VehicleState:
        """A snapshot of the vehicle; cheap and non-blocking (called at 10 Hz or more)."""


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
