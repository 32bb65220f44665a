"""The Tello adapter's own failsafes: a lost link, nobody commanding after it, a Tello that landed alone.

* **Link loss.** With no state for ``link_loss_timeout`` s the control thread sends one hover and then
  stays silent, so that the Tello's own 15 s failsafe lands it instead of our keepalives holding it up
  unseen (SDK 3.0 user guide, "Safety Function": it lands 15 s after the last command). Once it must
  have landed (15 s after our last command, or at once if it was on the ground) the thread sends
  ``command`` once a second, which re-enters SDK mode on a Tello that rebooted or forgot us.
* **Link back.** When state comes back the adapter re-reads the vehicle: on the ground it is GROUND;
  in the air it hovers for ``link_back_hover`` s waiting for a command (the HLC recovering from
  LLC_DOWN) and then lands it, so a Tello nobody commands any more is not held up forever.
* **A landing nobody commanded** (battery, the 15 s auto-landing, another client) is noticed from the
  state packets, and so is a Tello flying though we did not take off.

Every method runs with the adapter's lock held.
"""

from __future__ import annotations

import logging
import math

from antalate_lcm.vehicles.tello.commands import CommandChannel
from antalate_lcm.vehicles.tello.flight import TelloPhase
from antalate_lcm.vehicles.tello.maths import RC
from antalate_lcm.vehicles.tello.parts import Part, Shared

log = logging.getLogger("antalate.autopilot.tello")

PROBE_PERIOD = 1.0  # s between "command" probes while the link is lost


class Failsafes(Part):
    """The link-loss state (`silenced`) and the reactions to what the state packets show."""

    def __init__(self, shared: Shared, commands: CommandChannel) -> None:
        super().__init__(shared)
        self._commands = commands
        self.silenced = False  # link lost: no more commands until state comes back
        self._lost_in_air = False  # the Tello was flying when the link was lost
        self._last_probe = -math.inf

    def ingest(self) -> None:
        """Take in the newest state packet, if the link received one since the last call.

        The packet as a reading and a position (`PacketTracker.take`), then what the reading means
        for the adapter (a link back, a landing nobody commanded).
        """
        link = self._link()
        now = self._track.take(link.state() if link is not None else None)
        if now is None:
            return
        if self.silenced:
            # Whoever sees the first packet after a loss re-reads the vehicle, before anyone can act on
            # the fresh link: the HLC's state() may see it first and command an RTL within the same
            # tick, which a later re-read by the control thread would undo.
            self._link_back(now)
        self._track.air.update(self._track.in_air(), now)
        self._track_ground()

    def _track_ground(self) -> None:
        """Notice a Tello that landed (or took off) without us: its own failsafes, another client.

        Not while a command waits for its answer (that wait settles its own outcome) nor while the
        link is lost (the control thread re-reads the vehicle when it is back).
        """
        if self._commands.pending is not None or self.silenced:
            return
        f = self._flight
        if f.phase is not TelloPhase.GROUND and not self._track.air.value:
            if f.phase is not TelloPhase.LAND:
                log.warning(
                    "Tello %s is on the ground (landed by itself: battery, or 15 s without a command?)",
                    self._host,
                )
            f.to_ground()
        elif f.phase is TelloPhase.GROUND and self._track.air.value:
            log.warning(
                "Tello %s is flying though we did not take off: hovering under our control", self._host
            )
            f.phase = TelloPhase.GUIDED

    def link_lost(self, now: float) -> tuple[bool, RC | None]:
        """(lost, what to send): on the tick the link is found lost, one hover if it may be flying."""
        if self._track.age() <= self._p.link_loss_timeout:
            return False, None
        if self.silenced:
            return True, None
        self.silenced = True
        self._lost_in_air = self._track.in_air() or self._flight.phase is not TelloPhase.GROUND
        self._last_probe = now
        log.warning(
            "Tello %s: no state for %.1f s; stopped commanding it (it lands itself 15 s after "
            "the last command)",
            self._host,
            self._track.age(),
        )
        return True, (0, 0, 0, 0) if self._lost_in_air else None

    def unattended(self, now: float) -> bool:
        """Nobody commanded the Tello for ``link_back_hover`` s after a link loss: land it (True)."""
        f = self._flight
        if f.unattended_until is None or now < f.unattended_until or f.phase is not TelloPhase.GUIDED:
            return False
        f.unattended_until = None
        f.failsafe = (
            f"nobody commanded the Tello for {self._p.link_back_hover:g} s after a link loss: landing"
        )
        log.warning("Tello %s: %s", self._host, f.failsafe)
        f.phase = TelloPhase.LAND
        f.setpoint = None
        f.land_due = now
        return True

    def probe_due(self, now: float) -> bool:
        """While the link is lost: time to send ``command``?

        Not while the Tello may still be flying on its own: a probe that reaches it resets its 15 s
        auto-landing, and our keepalives are what the silence is there to stop.
        """
        if now - self._last_probe < PROBE_PERIOD or self._commands.pending is not None:
            return False  # (its "ok" would pass for the waiting command's answer)
        if self._lost_in_air and now - self._commands.last_sent < self._p.autoland_s:
            return False
        self._last_probe = now
        return True

    def _link_back(self, now: float) -> None:
        """State packets are back after a link loss: re-read the vehicle."""
        self.silenced = False
        track, f = self._track, self._flight
        track.air.reset(track.in_air())
        if not track.in_air():
            if f.phase is not TelloPhase.GROUND:
                log.warning("Tello %s: state is back; it landed during the link loss", self._host)
            else:
                log.info("Tello %s: state is back", self._host)
            f.to_ground()
            return
        if f.phase is TelloPhase.LAND:
            log.warning("Tello %s: state is back; still landing", self._host)
            f.land_due = now
            return
        if f.phase is TelloPhase.RTL:
            log.warning("Tello %s: state is back; going on home (dead reckoning missed the loss)", self._host)
            return
        f.phase = TelloPhase.GUIDED
        f.hold()
        f.unattended_until = now + self._p.link_back_hover
        log.warning(
            "Tello %s: state is back with the Tello in the air at %.1f m: hovering; it lands in "
            "%g s unless commanded",
            self._host,
            track.reading.height,
            self._p.link_back_hover,
        )
