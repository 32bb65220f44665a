"""The Tello's SDK command path: one datagram at a time, spaced, and the wait for its answer.

The Tello speaks the SDK text protocol: commands to UDP 8889 (most answered ``ok``/``error`` once
*done*, ``rc`` never answered), and a state line pushed to UDP 8890 about ten times a second.
djitellopy sends an answered command and then blocks on the one reply list it keeps per drone,
resending on a timeout (a second ``takeoff``!). The Tello's replies carry no id, so a late ``ok`` is
taken as the answer to the next command. Here an answered command is sent once (djitellopy's socket,
no retry) and its wait is a loop that also reads the state packets: a lost ``ok`` to ``takeoff`` is
settled once the state shows the Tello in the air and holding its height, a lost ``ok`` to ``land``
once it shows it on the ground; a read (``battery?``) skips a stray ``ok``. ``land``, ``rtl`` and
``emergency`` pre-empt a command that is still waiting (`CommandChannel.preempt`).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

from antalate_lcm.vehicles.base import AutopilotError
from antalate_lcm.vehicles.tello.link import TelloLink
from antalate_lcm.vehicles.tello.maths import RC
from antalate_lcm.vehicles.tello.parts import Part, Shared

log = logging.getLogger("antalate.autopilot.tello")

POLL = 0.02  # s between looks at the reply list and the state while a command waits


class Preempted(AutopilotError):
    """A waiting command was overtaken by land, rtl or emergency."""


class CommandChannel(Part):
    """Commands to one Tello and their answers.

    A wait takes in the state packets as they come (`Shared.ingest`, under the adapter's lock), so the
    adapter's picture of the Tello stays current while a command is out.
    """

    def __init__(self, shared: Shared) -> None:
        super().__init__(shared)
        self.cmd_lock = threading.RLock()  # one answered command at a time (replies carry no id)
        self._space_lock = threading.Lock()  # one non-rc datagram at a time, spaced (`_await_spacing`)
        self._quiet_since = -math.inf  # clock() of the last non-rc datagram sent or answer received
        self.last_sent = -math.inf  # clock() of the last datagram sent to the Tello
        self.pending: str | None = None  # the answered command waiting for its reply
        self.preempt = 0  # bumped by land/rtl/emergency: a waiting command gives up
        #: (command, deadline): an answer still owed by a command settled by the state (a take-off whose
        #: "ok" is late or lost); the next control command waits for it, so it cannot pass for its own
        self.owed: tuple[str, float] | None = None
        self.sent_at = -math.inf  # clock() when the waiting command went out

    def enter_sdk_mode(self, link: TelloLink) -> None:
        """``command`` until it is answered ``ok`` (connect's first step).

        This is djitellopy's ``Tello.connect()`` done by hand: its own waits 3 x 7 s for an answer,
        fixed; a dead host must fail in ``command_timeout`` x ``retry_count`` s, and the failure must
        say what to check.
        """
        p = self._p
        answer = ""
        for _ in range(p.retry_count):
            try:
                answer = self.exchange("command", p.command_timeout, preemptible=False)
            except AutopilotError as exc:
                answer = str(exc)
                continue
            if answer == "ok":
                return
        raise AutopilotError(
            f"no answer from the Tello at {link.where} to 'command' "
            f"({p.retry_count} x {p.command_timeout:g} s): is it on, and is this machine on its "
            f"Wi-Fi (or it on yours, in station mode)? ({answer})"
        )

    def _replies(self) -> list[bytes]:
        link = self._link()
        if link is None:
            raise AutopilotError(f"the link to the Tello at {self._host} is closed")
        return link.replies()

    def send(self, text: str) -> None:
        """One datagram to the Tello through the link (no retry); any but ``rc`` spaced."""
        link = self._link()
        if link is None:
            raise AutopilotError(f"{text!r}: not connected to the Tello at {self._host}")
        try:
            if text.startswith("rc "):
                link.send(text)
            else:
                with self._space_lock:
                    self._await_spacing()
                    link.send(text)
                    self._quiet_since = self._clock()
        except OSError as exc:
            raise AutopilotError(f"{text!r} to the Tello at {self._host} failed: {exc!r}") from exc
        finally:
            self.last_sent = self._clock()

    def send_rc(self, rc: RC) -> None:
        """Send ``rc`` (never answered: it cannot be mistaken for a reply)."""
        try:
            self.send("rc {} {} {} {}".format(*rc))
        except AutopilotError as exc:  # a failed send is a lost datagram, not a crash
            self._ratelog.log(("rc",), logging.WARNING, "Tello %s: rc not sent: %s", self._host, exc)

    def probe(self) -> None:
        """``command`` again: a Tello that rebooted or dropped us sends state only in SDK mode."""
        link = self._link()
        if link is None:
            return
        try:
            with self._space_lock:
                self._await_spacing()
                link.send("command")  # the "ok" is dropped by the next exchange
                self._quiet_since = self._clock()
        except OSError as exc:
            self._ratelog.log(("probe",), logging.WARNING, "Tello %s: probe not sent: %s", self._host, exc)

    def _await_spacing(self) -> None:
        """Sleep until ``command_spacing`` has passed since the last non-rc datagram or answer.

        A Tello ignores a command that comes too soon after the previous one or its answer, without a
        reply (djitellopy waits ``Tello.TIME_BTW_COMMANDS`` = 0.1 s after each answer: "Commands very
        consecutive makes the drone not respond to them"). ``rc`` is exempt, as in djitellopy
        (``TIME_BTW_RC_CONTROL_COMMANDS`` = 0.001 s)."""
        wait = self._quiet_since + self._p.command_spacing - self._clock()
        if wait > 0:
            time.sleep(wait)

    def _heard(self) -> None:
        """An answer came: the next command is spaced from now."""
        self._quiet_since = max(self._quiet_since, self._clock())

    def _settle_owed(self, replies: list[bytes], generation: int) -> None:
        """Wait for an answer a command settled by the state still owes, before a control command.

        Replies carry no id: a take-off's late "ok" arriving after the next command was sent would pass
        for that command's answer (and the Tello, still in its take-off, refuses a move with "error").
        Ends at the owed answer, its deadline, or a pre-emption.
        """
        while (owed := self.owed) is not None:  # land/emergency clear it from other threads
            what, deadline = owed
            if replies:
                answer = replies.pop(0).decode("utf-8", "replace").strip()
                self._heard()
                log.info("Tello %s: the late answer to %r came: %r", self._host, what, answer)
                self.owed = None
                return
            with self._lock:
                self._ingest()
                if self.preempt != generation:
                    raise Preempted(f"pre-empted while waiting for the answer to {what!r}")
            if self._clock() >= deadline:
                log.info("Tello %s: no answer to %r came (lost)", self._host, what)
                self.owed = None
                return
            if self._stop.is_set():
                raise AutopilotError("the adapter is closing")
            time.sleep(POLL)

    def exchange(
        self,
        text: str,
        timeout: float,
        *,
        settled: Callable[[], bool] | None = None,
        done_in_air: bool = False,
        preemptible: bool = True,
    ) -> str:
        """Send an answered command once and wait for its answer; ``""`` when `settled` said done first.

        `settled` (called with the state lock held, after each state packet is taken in) lets the state
        packets answer for a reply that was lost. A timeout raises `AutopilotError`, except that with
        `done_in_air` a Tello seen flying at the deadline counts as done (a take-off whose ``ok`` was lost
        while the height kept wandering). land/rtl/emergency raise `Preempted` in a `preemptible` wait.
        """
        with self._lock:
            generation = self.preempt
        with self.cmd_lock:
            with self._lock:
                if preemptible and self.preempt != generation:
                    raise Preempted(f"{text!r} pre-empted before it was sent")
                self.pending = text
            try:
                replies = self._replies()
                if preemptible and not text.endswith("?"):
                    self._settle_owed(replies, generation)  # (a read skips a stray "ok" itself)
                with self._space_lock:
                    self._await_spacing()
                if replies:
                    self._heard()
                replies.clear()  # late replies to earlier commands, which would pass for this one's
                self.send(text)
                with self._lock:
                    self.sent_at = self._clock()
                deadline = self._clock() + timeout
                while True:
                    while replies:
                        answer = replies.pop(0).decode("utf-8", "replace").strip()
                        self._heard()
                        if text.endswith("?") and answer.lower() == "ok":
                            continue  # a read is never answered "ok": a late reply to a control command
                        return answer
                    with self._lock:
                        self._ingest()
                        if preemptible and self.preempt != generation:
                            raise Preempted(f"{text!r} pre-empted")
                        if settled is not None and settled():
                            return ""
                        if self._clock() >= deadline:
                            if done_in_air and self._track.air.value:
                                return ""
                            raise AutopilotError(
                                f"the Tello at {self._host} did not answer {text!r} within {timeout:g} s"
                            )
                    if self._stop.is_set():
                        raise AutopilotError(f"{text!r}: the adapter is closing")
                    time.sleep(POLL)
            finally:
                with self._lock:
                    self.pending = None
