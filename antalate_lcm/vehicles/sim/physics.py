"""`Quadcopter`: the sim's kinematic model -- the vehicle's state and its integration over simulated time.

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
  the air forces a LAND with failsafe "battery empty" (the autopilot's own failsafe).
* Battery drains ``drain_flying`` %/min in the air and ``drain_idle`` %/min on the ground (its voltage
  and warning: `telemetry`).

Time
----
The simulation advances lazily: whenever `state()` or a command is called, it integrates from the
previous call to ``clock()`` (scaled by ``time_scale``) in steps of at most ``max_step`` seconds
(in one go while idle on the ground, and in GUIDED flight when no set-point expiry, empty battery or
touchdown can fall inside the interval: the lag is exact for any step, see ``_one_step``; a still,
uncommanded hover is that step's battery drain alone, ``_hover``). Nothing
runs between calls, so hundreds of sims cost nothing while idle, and tests drive time with a fake
clock. Autopilot timers (auto-disarm, velocity hold, ...) run on simulated time;
`VehicleState.link_age` is in real (clock) seconds, as the HLC perceives it.
"""

from __future__ import annotations

import enum
import math

from antalate_lcm.base.geo import FlatFrame, body_to_ne, wrap_360
from antalate_lcm.vehicles.base import Clock, Frame
from antalate_lcm.vehicles.sim.params import Params, shared

__all__ = ["PERSISTED", "Motion", "Quadcopter"]

_HOME_RADIUS = 0.05  # m: close enough to home to start the RTL descent
_RADIANS = math.pi / 180.0  # per degree: what `math.radians` multiplies by (Modules/mathmodule.c)


class Motion(enum.Enum):
    """What the kinematic model is doing (the Tello adapter's `_Phase` is a different thing: its mode)."""

    GROUND = "ground"
    CLIMB = "climb"  # takeoff
    GUIDED = "guided"  # following velocity set-points (hover without)
    RETURN = "return"  # RTL leg home
    DESCEND = "descend"  # LAND, end of RTL, or the pilot landing
    PILOT = "pilot"  # a pilot holds the vehicle
    HOLD = "hold"  # the autopilot brakes and holds position (failsafe BRAKE)


# The members bound once: in CPython 3.11 reading ``Motion.GROUND`` calls the enum's descriptor
# (~125 ns, an attribute read ~10), and each poll of a thousand sims compares a few of them.
M_GROUND, M_CLIMB, M_GUIDED, M_RETURN = Motion.GROUND, Motion.CLIMB, Motion.GUIDED, Motion.RETURN
M_DESCEND, M_PILOT, M_HOLD = Motion.DESCEND, Motion.PILOT, Motion.HOLD
_BODY = Frame.BODY

#: What a vehicle keeps across a restart of the software that flies it (`persistence`), with its motion.
PERSISTED = (
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


class Quadcopter:
    """The vehicle as its autopilot flies it: no link, no contract (`faults`, `adapter` add those),
    no report (`telemetry`).

    A base of `SimAdapter`, which provides ``clock`` (`VehicleAdapter`); `_init_state` stands in for a
    constructor, so that the adapter keeps the `VehicleAdapter` constructor's signature.
    """

    # Slots: an instance with more than 30 attributes in its __dict__ loses CPython's shared-key
    # dict (3.11: every attribute read a hash lookup in a 1.6 KB table of its own); a thousand
    # sims are polled 20 times a second each. Subclasses and the base's attributes keep a __dict__.
    __slots__ = (
        *PERSISTED,
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
        "_step_lag",
        "_phase",
        "_cmd",
        "_cmd_time",
        "_armed_since",
        "_disarm_at",
        "_takeover_time",
        "_pilot_autoland",
        "_sim_time",
        "_t_last",
        "_airborne_since",
        "_battery_params",
        "_drain",
        "_latlon_n",
        "_latlon_e",
        "_latlon",
    )
    clock: Clock

    def _init_state(self, p: Params, now: float) -> None:
        """On the ground at home, disarmed, at ``now`` of the clock."""
        self._p = p
        self.home = FlatFrame(p.home_lat, p.home_lon)
        self._tau = p.tau
        self._time_scale = p.time_scale
        self._max_step = p.max_step
        #: Read by every step of flight (the parameters never change after construction).
        self._velocity_hold = p.velocity_hold
        self._max_speed = p.max_speed
        self._climb_rate = p.climb_rate
        self._descent_rate = p.descent_rate
        self._max_yaw_rate = p.max_yaw_rate
        #: `_lag`'s decay and distance factor over a step of ``max_step`` (`_fly`'s usual step).
        decay = math.exp(-p.max_step / p.tau)
        self._step_lag = shared((p.max_step, decay, p.tau * (1.0 - decay)))
        # Vehicle state (local frame: metres north/east of home, altitude above home).
        self.north = self.east = self.alt = 0.0
        self.vn = self.ve = self.vd = 0.0
        self.heading = wrap_360(p.heading)
        self.battery = self._check_battery(p.battery)
        self.armed = False
        self.in_air = False
        self.mode = "GUIDED"
        self._failsafe = ""  # the active failsafe's reason
        self._phase = M_GROUND
        self._takeoff_alt = 0.0
        self._cmd: tuple[float, float, float, float, Frame] | None = None  # vx, vy, vz, yaw_rate, frame
        self._cmd_time = 0.0
        self._armed_since: float | None = None  # sim time the vehicle was armed on the ground
        self._disarm_at: float | None = None  # sim time of a pending post-landing disarm
        self._takeover_time = 0.0
        self._pilot_autoland = p.takeover_autoland
        self._sim_time = 0.0
        self._t_last = now
        self._airborne_since: float | None = None  # sim time of the last takeoff
        #: cells, voltage sag per cell in the air, warning level (%): read by every `telemetry.snapshot`.
        self._battery_params = shared((p.cells, p.voltage_sag, p.battery_warning_at))
        #: %/min drained on the ground and in the air (indexed by `in_air`: read every step).
        self._drain = shared((p.drain_idle, p.drain_flying))
        #: `telemetry.snapshot`'s: the last lat/lon and the (north, east) it is of.
        self._latlon_n, self._latlon_e, self._latlon = math.nan, math.nan, (0.0, 0.0)

    @property
    def sim_time(self) -> float:
        """Simulated seconds since construction."""
        return self._sim_time

    @staticmethod
    def _check_battery(percent: float) -> float:
        if not (math.isfinite(percent) and 0.0 <= percent <= 100.0):
            raise ValueError(f"battery must be in [0, 100] percent, got {percent!r}")
        return percent

    def _switch_mode(self, mode: str, motion: Motion, failsafe: str = "") -> None:
        """The autopilot switches to `mode` (a command or its own failsafe): the set-point is dropped;
        in the air the vehicle flies `motion`, on the ground an armed one disarms."""
        self.mode = mode
        self._failsafe = failsafe
        self._cmd = None
        if self.in_air:
            self._phase = motion
        elif self.armed:
            self._disarm()

    def _disarm(self) -> None:
        self.armed = False
        self._armed_since = None
        self._disarm_at = None

    # ----------------------------------------------------------------- integration

    def _advance(self) -> None:
        now = self.clock()
        dt = now - self._t_last
        self._t_last = now
        if not dt > 0.0:  # (``max(0.0, dt)`` scaled: a clock that stood still or ran back)
            return
        dt *= self._time_scale
        if dt <= 0.0:
            return
        phase = self._phase
        if phase is M_GROUND and self._armed_since is None and self._disarm_at is None and not self.in_air:
            # Disarmed on the ground (20 polls a second, most of a swarm's life): `_step`'s work
            # there is the battery's idle drain and nothing moving.
            self._sim_time += dt
            battery = self.battery - self._drain[False] * dt / 60.0
            self.battery = battery if battery > 0.0 else 0.0  # max(0.0, battery), as `_step`
            self.vn = self.ve = self.vd = 0.0
            return
        if phase is M_GROUND or (phase is M_GUIDED and self._one_step(dt)):
            # Nothing moves, or the set-point is followed exactly in one step (`_lag`): the HLC
            # polls at 20 Hz, a period just over ``max_step``, which cut each poll in two steps.
            if phase is M_GUIDED and not (self.vn or self.ve or self.vd) and self._hover(dt):
                return
            if phase is M_GUIDED and self.in_air:
                dt = self._fly(dt, dt)
                if dt <= 0.0:
                    return
            self._step(dt)
            return
        if phase is M_GUIDED and self.in_air:
            dt = self._fly(dt, self._max_step)
        while dt > 0.0:
            if self._phase is M_GROUND:
                self._step(dt)  # nothing moves: one step, however long
                return
            h = min(dt, self._max_step)
            self._step(h)
            dt -= h

    def _fly(self, dt: float, max_step: float) -> float:
        """``dt`` s of GUIDED flight in the air in steps of at most ``max_step``, each `_step`'s float
        for float on local variables (a swarm's 20 polls a second per agent: a turning body-frame
        set-point, two steps a poll on simulated time's grid); the seconds left at an event: a step
        that would empty the battery is left to `_step` (its LAND), a touchdown calls `_touchdown`.
        tests/vehicles/test_sim_snapshot.py runs it beside `_step` bit for bit.
        """
        tau, hold, max_speed = self._tau, self._velocity_hold, self._max_speed
        drain, t, battery = self._drain[True], self._sim_time, self.battery
        north, east, alt = self.north, self.east, self.alt
        vn, ve, vd = self.vn, self.ve, self.vd
        heading, cmd, cmd_time = self.heading, self._cmd, self._cmd_time
        body = may_clamp = False
        vx = vy = tn0 = te0 = td0 = yaw0 = 0.0
        if cmd is not None:  # `_follow_setpoint`'s arithmetic of what the step does not change
            vx, vy, vz, yaw, frame = cmd
            body = frame is _BODY
            # max(-limit, min(limit, x)) without the calls: each keeps its first argument unless
            # the second is strictly beyond it (the same float, signed zeros included).
            limit = self._descent_rate
            td0 = vz if vz < limit else limit
            limit = -self._climb_rate
            td0 = td0 if td0 > limit else limit
            limit = self._max_yaw_rate
            yaw0 = yaw if yaw < limit else limit
            limit = -limit
            yaw0 = yaw0 if yaw0 > limit else limit
            if body:
                # A rotation keeps the length to a few ulps: far below the limit no clamp can apply.
                may_clamp = math.hypot(vx, vy) > max_speed * (1.0 - 1e-9)
            else:
                tn0, te0 = vx, vy
                speed = math.hypot(vx, vy)
                if speed > max_speed:
                    tn0, te0 = vx * max_speed / speed, vy * max_speed / speed
        step, step_decay, step_keep = self._step_lag
        touchdown = False
        while dt > 0.0:
            h = max_step if max_step < dt else dt  # min(dt, max_step)
            left = battery - drain * h / 60.0
            if not left > 0.0:
                break  # the battery runs out: `_step`'s failsafe LAND
            battery = left
            t += h
            tn = te = td = yaw_rate = 0.0
            if cmd is not None and t - cmd_time <= hold:
                td, yaw_rate = td0, yaw0
                if body:  # `body_to_ne`
                    psi = heading * _RADIANS  # math.radians(heading), float for float
                    c, s = math.cos(psi), math.sin(psi)
                    tn, te = vx * c - vy * s, vx * s + vy * c
                    if may_clamp:
                        speed = math.hypot(tn, te)
                        if speed > max_speed:
                            tn, te = tn * max_speed / speed, te * max_speed / speed
                else:
                    tn, te = tn0, te0
            if h == step:
                decay, keep = step_decay, step_keep
            else:
                decay = math.exp(-h / tau)
                keep = tau * (1.0 - decay)
            north += tn * h + (vn - tn) * keep
            east += te * h + (ve - te) * keep
            down = alt - (td * h + (vd - td) * keep)
            alt = down if down > 0.0 else 0.0  # max(0.0, down)
            vn = tn + (vn - tn) * decay
            ve = te + (ve - te) * decay
            vd = td + (vd - td) * decay
            if yaw_rate:  # `wrap_360`
                turned = math.fmod(heading + yaw_rate * h, 360.0)
                if turned < 0.0:
                    turned += 360.0
                heading = 0.0 if turned >= 360.0 else turned
            dt -= h
            if alt <= 0.0:
                touchdown = True
                break
        self._sim_time, self.battery, self.heading = t, battery, heading
        self.north, self.east, self.alt = north, east, alt
        self.vn, self.ve, self.vd = vn, ve, vd
        if touchdown:
            self._touchdown()
        return dt

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

    def _hover(self, dt: float) -> bool:
        """`_step` of ``dt`` s hovering (GUIDED, still, no set-point in force after the step, and
        `_one_step` true: no empty battery, no touchdown), when it is one; False, nothing done, else.

        A swarm in MISSION without a behavior hovers, 20 polls a second per agent: the lag toward zero
        from zero leaves the velocities 0.0 and the position as it is but for a -0.0 made 0.0 (by its
        ``+ 0.0``; any other float kept, the object the snapshot's copy compares): the battery's drain.
        """
        t = self._sim_time + dt
        if self._cmd is not None and t - self._cmd_time <= self._velocity_hold:
            return False
        self._sim_time = t
        battery = self.battery - self._drain[self.in_air] * dt / 60.0
        self.battery = battery if battery > 0.0 else 0.0  # max(0.0, battery)
        self.vn = self.ve = self.vd = 0.0
        if self.north == 0.0:
            self.north = 0.0
        if self.east == 0.0:
            self.east = 0.0
        return True

    def _step(self, h: float) -> None:
        p = self._p
        self._sim_time += h
        t = self._sim_time
        drain = self._drain[self.in_air]
        self.battery = max(0.0, self.battery - drain * h / 60.0)
        if self.in_air and self.battery <= 0.0 and self._phase is not M_DESCEND:
            self._switch_mode("LAND", M_DESCEND, "battery empty")  # the autopilot's own failsafe

        phase = self._phase
        if phase is M_GROUND:
            self.vn = self.ve = self.vd = 0.0
            if self._armed_since is not None or self._disarm_at is not None:
                landed_long_enough = self._disarm_at is not None and t >= self._disarm_at
                idle_too_long = self._armed_since is not None and t - self._armed_since >= p.auto_disarm_delay
                if landed_long_enough or idle_too_long:
                    self._disarm()
        elif phase is M_CLIMB:
            self._brake(h)
            self._vertical_to(self._takeoff_alt, self._climb_rate, h)
            if self.alt >= self._takeoff_alt:
                self._phase = M_GUIDED
        elif phase is M_GUIDED:
            self._follow_setpoint(h)
        elif phase is M_RETURN:
            self._return_home(h)
        elif phase is M_DESCEND:
            self._brake(h)
            self._vertical_to(0.0, self._descent_rate, h)
        elif phase is M_HOLD:
            self._brake(h)
            self.vd = 0.0
        elif phase is M_PILOT:
            self._brake(h)
            self.vd = 0.0
            if self._pilot_autoland and t - self._takeover_time >= p.takeover_land_delay:
                self._phase = M_DESCEND
        if self.in_air and self.alt <= 0.0 and self._phase is not M_CLIMB:
            self._touchdown()

    def _lag(self, v0: float, target: float, h: float) -> tuple[float, float]:
        """Velocity after `h` s and distance covered, following `target` with the time constant: exact
        for a set-point held constant over the step, so results do not depend on the step size."""
        decay = math.exp(-h / self._tau)
        v1 = target + (v0 - target) * decay
        return v1, target * h + (v0 - target) * self._tau * (1.0 - decay)

    def _brake(self, h: float) -> None:
        if not (self.vn or self.ve):  # still (a climb, a descent): no exponential needed
            self.vn = self.ve = 0.0  # `_lag` toward 0.0 from a zero, and its distance 0.0 added
            self.north += 0.0  # (a -0.0 made 0.0)
            self.east += 0.0
            return
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
        rtl_alt = p.rtl_altitude
        if self.alt < rtl_alt:
            self.vn = self.ve = 0.0
            self._vertical_to(rtl_alt, self._climb_rate, h)
            return
        self.vd = 0.0
        dist = math.hypot(self.north, self.east)
        speed = p.rtl_speed
        if dist <= max(_HOME_RADIUS, speed * h):
            # Arrive exactly (within one step's travel), stop, and descend.
            self.north = self.east = 0.0
            self.vn = self.ve = 0.0
            self._phase = M_DESCEND
            return
        self.vn, self.ve = -self.north / dist * speed, -self.east / dist * speed
        self.north += self.vn * h
        self.east += self.ve * h
        self.heading = wrap_360(math.degrees(math.atan2(self.ve, self.vn)))

    def _touchdown(self) -> None:
        self.alt = 0.0
        self.vn = self.ve = self.vd = 0.0
        self.in_air = False
        self._phase = M_GROUND
        self._failsafe = ""
        self._cmd = None
        if self.armed:
            if self.mode == "GUIDED":
                self._armed_since = self._sim_time  # ArduCopter: disarm if left idle on the ground
            else:
                self._disarm_at = self._sim_time + self._p.land_disarm_delay
