"""`TelloAdapter`: a DJI/Ryze Tello over Wi-Fi through djitellopy (docs/design.md §7, ``tello``).

The Tello speaks the SDK text protocol: commands to UDP 8889 (most answered ``ok``/``error`` once
*done*, ``rc`` never answered), and a state line pushed to UDP 8890 about ten times a second. It
has no GPS, no arming step and no return-to-home, so this adapter supplies what the HLC expects on
top of it. The user-facing description (set-up, several Tellos, limits) is ``docs/tello.md``.

What the adapter adds, and where
--------------------------------
* **Position by dead reckoning** from the state packets, and the link age: `tracking`.
* **Its own command path** (sent once, spaced, its answer waited for while the state packets are
  read, pre-empted by ``land``, ``rtl`` and `emergency`): `commands`.
* **The link** (`link.TelloLink`) is given by the caller: djitellopy's sockets by default,
  `link.MemoryLink` to a peer in this process in tests (no socket, the same adapter).
* **A control thread** at ``control_hz`` streaming ``rc`` and keepalives: `control`.
* **Link loss**, link back, a landing nobody commanded: `failsafe`.
* **RTL** = fly back to the take-off point at ``rtl_speed`` with ``rc``, then ``land``: `rtl`;
  landing itself (settled by the answer or the state, retried): `landing`.
* **Take-off to an altitude** (the Tello's own ``takeoff`` stops at about 0.8 m): `takeoff`.
* **No arming.** The motors start with ``takeoff``. `arm` checks the link, that a command is
  answered (``battery?``) and the battery; `disarm` is a no-op on the ground.

The arithmetic is in `maths`, the parameters in `params`, the phase in `flight`.

One process, several Tellos: djitellopy binds UDP 8889 and 8890 on all addresses once per process
and files replies and state packets by the sender's IP. Several Tellos are therefore several agents
of one ``antalate agent`` process, each with its own ``host``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import TYPE_CHECKING, ClassVar

from pydantic import BaseModel

from antalate_lcm.base.deprecation import renamed_names
from antalate_lcm.base.geo import FlatFrame
from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.vehicles.base import (
    AutopilotError,
    FlightMode,
    Frame,
    VehicleState,
    check_takeoff_altitude,
    check_velocity,
)
from antalate_lcm.vehicles.kit import LinkedAdapter
from antalate_lcm.vehicles.tello.commands import POLL, CommandChannel
from antalate_lcm.vehicles.tello.control import ControlLoop, Sticks
from antalate_lcm.vehicles.tello.failsafe import Failsafes
from antalate_lcm.vehicles.tello.flight import FLIGHT_MODES, Flight, TelloPhase
from antalate_lcm.vehicles.tello.landing import Lander
from antalate_lcm.vehicles.tello.link import DjitellopyLink, TelloLink
from antalate_lcm.vehicles.tello.params import Params
from antalate_lcm.vehicles.tello.parts import Shared
from antalate_lcm.vehicles.tello.rtl import ReturnHome
from antalate_lcm.vehicles.tello.takeoff import Takeoff
from antalate_lcm.vehicles.tello.tracking import PacketTracker

log = logging.getLogger("antalate.autopilot.tello")


class TelloAdapter(LinkedAdapter[Params, TelloLink]):
    """A Tello through djitellopy; see the module docstring for what is emulated on top of the SDK."""

    name = "tello"
    blocking = True  # takeoff/land/up wait for the Tello's answer, which comes when the move is done
    params_model: ClassVar[type[BaseModel]] = Params

    def _setup(self) -> None:
        """The constructor's ``link=`` opens the link at `connect` (`link.MemoryLink` in tests; default
        djitellopy's sockets, `_default_link`)."""
        p = self._p
        self.host: str = p.host
        self.home = FlatFrame(p.home_lat, p.home_lon)
        self._link: TelloLink | None = None  # once connected
        self._lock = threading.RLock()  # adapter state, shared by the HLC, control and caller threads
        self._connected = False
        self._track = PacketTracker(p, self.clock, self.host)
        self._flight = Flight()
        shared = Shared(
            p=p,
            clock=self.clock,
            host=self.host,
            lock=self._lock,
            stop=self._stop,
            ratelog=RateLimitedLog(log, period=10.0, clock=self.clock),
            link=lambda: self._link,
            ingest=self._ingest,
            track=self._track,
            flight=self._flight,
        )
        self._cmd = CommandChannel(shared)
        self._failsafes = Failsafes(shared, self._cmd)
        self._rtl = ReturnHome(shared)
        self._lander = Lander(shared, self._cmd)
        self._takeoff = Takeoff(shared, self._cmd)
        self._rc = Sticks(p, self._track)
        self._control = ControlLoop(
            shared, self._cmd, failsafes=self._failsafes, rtl=self._rtl, lander=self._lander, sticks=self._rc
        )

    def _default_link(self, params: Params) -> TelloLink:
        """djitellopy's sockets to ``host``."""
        return DjitellopyLink(params)

    # ================================================================= the adapter contract

    def connect(self) -> None:
        if self._connected:
            return
        link = self._opener(self._p)
        link.open()
        self._link = link
        try:
            self._open(link)
        except BaseException:
            self._release()
            raise
        self._connected = True
        self._workers.start((self._control.run, f"tello-{self.host}"))
        log.info(
            "Tello %s connected: battery %s%%, %s",
            self.host,
            self._track.reading.battery,
            "flying" if self._flight.phase is not TelloPhase.GROUND else "on the ground",
        )

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            self._cmd.preempt += 1
        self._workers.halt()
        if self._link is not None and self._connected:
            with self._lock:
                flying = self._flight.phase is not TelloPhase.GROUND
            if flying:
                # Hover and let go: the Tello's own 15 s failsafe lands it unless a restarted HLC
                # takes over first (a vehicle outlives the software flying it).
                self._cmd.send_rc((0, 0, 0, 0))
                log.warning("Tello %s left hovering; it lands itself 15 s after the last command", self.host)
        self._connected = False
        self._release()

    def arm(self) -> bool:
        self._require_link("arm")
        answer = self._cmd.exchange("battery?", self._p.command_timeout)
        try:
            battery = float(answer)
        except ValueError:
            raise AutopilotError(
                f"arm: the Tello at {self.host} did not answer 'battery?' ({answer!r})"
            ) from None
        if battery <= self._p.min_battery:
            log.warning("arm refused: battery %.0f%% <= min_battery %g%%", battery, self._p.min_battery)
            return False
        return True

    def disarm(self) -> None:
        self._require_connected("disarm")
        with self._lock:
            if self._track.in_air():
                raise AutopilotError(
                    "disarm refused: the Tello is flying (its only disarm, 'emergency', "
                    "cuts the motors in the air)"
                )

    def takeoff(self, alt: float) -> None:
        self._require_link("takeoff")
        check_takeoff_altitude(alt)
        self._takeoff.fly(alt)

    def land(self) -> None:
        self._require_connected("land")
        f = self._flight
        with self._lock:
            self._flight.commanded()
            f.hold()
            self._cmd.preempt += 1  # a waiting takeoff/up gives up at once
            self._cmd.owed = None  # a landing supersedes a take-off still running
            if f.phase is TelloPhase.GROUND and not self._track.in_air():
                return  # nothing to land
            f.phase = TelloPhase.LAND
            f.land_due = None
        self._cmd.send_rc((0, 0, 0, 0))
        self._lander.land_now()

    def rtl(self) -> None:
        self._require_link("rtl")
        f = self._flight
        with self._lock:
            self._flight.commanded()
            if not self._track.in_air() and f.phase in (TelloPhase.GROUND, TelloPhase.TAKEOFF):
                return  # on the ground there is nowhere to return from
            if f.phase in (TelloPhase.RTL, TelloPhase.LAND):
                return  # already on the way (or down)
            self._cmd.preempt += 1
            dist0 = self._rtl.start()
        self._rtl.verify(dist0)

    def set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame) -> None:
        check_velocity(vx, vy, vz, yaw_rate)
        self._require_link("set_velocity")
        f = self._flight
        with self._lock:
            self._ingest()
            if f.phase is TelloPhase.TAKEOFF and f.climb_target is not None:
                f.climb_target = None  # the caller takes over from the climb
                f.phase = TelloPhase.GUIDED
            if f.phase is not TelloPhase.GUIDED:
                return  # like ArduCopter: velocity targets are ignored outside guided flight
            self._flight.commanded()
            # Streamed by the control thread on its schedule: sending here too made the rc rate
            # control_hz plus the HLC's command rate.
            f.setpoint = (vx, vy, vz, yaw_rate, Frame(frame))
            f.setpoint_time = self.clock()

    def state(self) -> VehicleState:
        with self._lock:
            if not self._connected:
                return VehicleState(connected=False, link_age=math.inf)
            self._ingest()
            track, r, phase = self._track, self._track.reading, self._flight.phase
            lat, lon = self.home.to_latlon(track.north, track.east)
            # Until the Tello confirms a landing the motors may still turn: the HLC must not see
            # "landed" (and command the next take-off) while the final centimetres, which the state's
            # decimetre height already rounds to zero, are being flown.
            in_air = track.in_air() or phase is TelloPhase.LAND
            return VehicleState(
                connected=True,
                link_age=track.age(),
                lat=lat,
                lon=lon,
                alt=r.height,
                heading=track.heading(),
                vn=r.vn,
                ve=r.ve,
                vd=r.vd,
                battery=r.battery,
                armed=in_air,  # a Tello's motors run exactly while it flies
                in_air=in_air,
                autonomous=True,  # no pilot radio: always under computer control
                mode=phase.value,
                flight_mode=FLIGHT_MODES.get(phase, FlightMode.GUIDED),
                failsafe=self._flight.failsafe if phase is TelloPhase.LAND else "",
            )

    # ================================================================= extras (tests, tools)

    def emergency(self) -> None:
        """Stop the motors at once (the Tello drops): pre-empts any command still waiting."""
        self._require_connected("emergency")
        with self._lock:
            self._cmd.preempt += 1
            self._flight.hold()
            self._flight.phase = TelloPhase.GROUND
            self._track.air.reset(False)  # it drops: not "flying though we did not take off"
            self._flight.land_due = None
            self._cmd.owed = None
        # never answered (SDK guide; djitellopy sends it without waiting): nothing to wait for but the
        # command spacing, without which the Tello would not hear it
        self._cmd.send("emergency")
        log.warning("Tello %s: emergency (motors stopped)", self.host)

    @property
    def position_ne(self) -> tuple[float, float]:
        """Dead-reckoned metres north/east of home (for tests and tools)."""
        with self._lock:
            return self._track.north, self._track.east

    @property
    def dead_reckoning_problem(self) -> str:
        """Why the state's velocities cannot be dead-reckoned (`maths.VelocityUnitCheck`); "" while none."""
        with self._lock:
            return self._track.units.problem

    @property
    def takeoff_point(self) -> tuple[float, float]:
        """Where the last take-off began, metres north/east of home: the RTL's destination."""
        with self._lock:
            return self._flight.takeoff_point

    # ================================================================= connect's I/O, checks

    def _open(self, link: TelloLink) -> None:
        """Enter SDK mode and wait for state on the open `link` (connect's I/O).

        djitellopy's ``Tello.connect()`` waits 1 s for state, fixed; here ``state_timeout``, and the
        failure says what to check.
        """
        self._cmd.enter_sdk_mode(link)
        p, f, track = self._p, self._flight, self._track
        deadline = self.clock() + p.state_timeout
        while True:
            with self._lock:
                self._ingest()
                if track.age.heard_at is not None:
                    track.air.reset(track.in_air())
                    f.phase = TelloPhase.GUIDED if track.in_air() else TelloPhase.GROUND
                    f.takeoff_point = (track.north, track.east)
                    return
            if self.clock() >= deadline:
                raise AutopilotError(
                    f"the Tello at {self.host} entered SDK mode but sent no state packet to "
                    f"{link.state_where} within {p.state_timeout:g} s (a firewall, or another "
                    "program bound to that port?)"
                )
            time.sleep(POLL)

    def _release(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            link.close()

    def _require_connected(self, what: str) -> None:
        if not self._connected or self._link is None:
            raise AutopilotError(f"{what}: not connected to the Tello at {self.host}")

    def _require_link(self, what: str) -> None:
        self._require_connected(what)
        with self._lock:
            self._ingest()
            age = self._track.age()
        if age > self._p.link_loss_timeout:
            raise AutopilotError(
                f"{what}: no state from the Tello at {self.host} for {age:.1f} s (link lost)"
            )

    def _ingest(self) -> None:
        """Take in the newest state packet and react to it (lock held): `failsafe.Failsafes.ingest`."""
        self._failsafes.ingest()


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
