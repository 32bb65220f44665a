"""Operator commands until acknowledged, and the operator's direction (pure: no Textual, no LCM I/O).

Acknowledgement (docs/design.md §5, §10)
--------------------------------
Every TAKEOFF/LAND/RTL the console sends gets a ``seq`` of its own (``header.seq``). The MC
acknowledges by publishing ``mc_state_t.last_command_seq == seq`` once it *accepted* the command.
Equality, not "≥": the MC stores the seq of the last accepted command from *any* sender (this
console, another console, an auto-operator), so a larger number proves nothing about ours, and a
number left over from an earlier session must not acknowledge a new command. For the same reason
the first seq of a session is random: the MC remembers accepted ``(sender, seq, command)`` for a
minute to drop duplicates, so a restarted console counting from 1 again would be ignored.

Until acknowledged, a command is resent every ``resend_interval`` seconds *with the same seq* (the
MC treats duplicates idempotently), and after ``timeout`` seconds it is marked failed. The MC also
rejects, without acknowledging, a command that does not apply in its state (LAND while on the
ground): that looks exactly like a loss, so the failure reason says which is more likely from the
MC state the console last saw.

If one of our *later* commands to the same agent is acknowledged first, the earlier one is
*superseded*: once the MC moved on, its fate no longer matters (and its own ack, if it was sent
while we missed it, will never be repeated).

A command to every agent goes once on the broadcast channel; it waits for an ack from each agent
that was live when it was sent, and is resent on the broadcast channel while any is missing.
"""

from __future__ import annotations

import enum
import random
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from antalate_lcm.msgs import operator_cmd_t

#: Operator commands by name (wire values from the generated constants).
COMMANDS: dict[str, int] = {
    "TAKEOFF": operator_cmd_t.TAKEOFF,
    "LAND": operator_cmd_t.LAND,
    "RTL": operator_cmd_t.RTL,
}

#: MC states in which each command is accepted (docs/design.md §5). Only a *hint* for failure reasons and
#: for the warning shown when sending: the MC is the authority and the console never refuses to send.
APPLIES_IN: dict[str, frozenset[str]] = {
    "TAKEOFF": frozenset({"STANDBY"}),
    "LAND": frozenset({"TAKEOFF", "MISSION", "RTL", "HOLD"}),  # and ERROR once the HLC's link is up
    "RTL": frozenset({"TAKEOFF", "MISSION", "HOLD"}),
}

SEQ_MAX = 2**31 - 1


def applies(command: str, mc_state: str | None) -> bool | None:
    """Whether ``command`` should be accepted in ``mc_state``; None when the state is unknown."""
    if mc_state is None:
        return None
    return mc_state in APPLIES_IN.get(command, frozenset())


class Status(enum.Enum):
    PENDING = "pending"
    ACKED = "acked"
    FAILED = "failed"


@dataclass
class TrackedCommand:
    """One operator command and what has been heard about it."""

    seq: int
    command: str
    #: Agent name, or "" for every agent (sent on the broadcast channel).
    target: str
    altitude: float
    sent_at: float
    last_sent: float
    #: Agents whose ack is awaited (the target, or the live agents when it was broadcast).
    expected: frozenset[str]
    acked: set[str] = field(default_factory=set)
    superseded: set[str] = field(default_factory=set)
    sends: int = 1
    status: Status = Status.PENDING
    reason: str = ""
    done_at: float | None = None

    @property
    def broadcast(self) -> bool:
        return not self.target

    @property
    def label(self) -> str:
        to = self.target or f"ALL ({len(self.expected)})"
        return f"{self.command} → {to}"

    @property
    def settled(self) -> set[str]:
        return self.acked | self.superseded

    @property
    def progress(self) -> str:
        """'2/3': how many of the expected agents have acknowledged (or moved past) it."""
        return f"{len(self.expected & self.settled)}/{len(self.expected)}"

    @property
    def missing(self) -> list[str]:
        return sorted(self.expected - self.settled)

    def age(self, now: float) -> float:
        return (self.done_at if self.done_at is not None else now) - self.sent_at


@dataclass(frozen=True)
class CommandUpdate:
    """Something the UI should log about a command: acknowledged, superseded, failed."""

    command: TrackedCommand
    text: str
    failed: bool = False


class CommandTracker:
    """Assigns seqs, matches acks, schedules resends and declares failures.

    The caller does the sending: :meth:`new` returns the command to send first, :meth:`tick`
    returns the commands due for a resend (same seq).
    """

    def __init__(
        self,
        *,
        resend_interval: float = 1.0,
        timeout: float = 10.0,
        first_seq: int | None = None,
        history: int = 50,
        rng: random.Random | None = None,
    ) -> None:
        if not (resend_interval > 0 and timeout > 0):
            raise ValueError("resend_interval and timeout must be > 0")
        self.resend_interval = resend_interval
        self.timeout = timeout
        self._next_seq = (
            first_seq if first_seq is not None else (rng or random.SystemRandom()).randint(1, 2**30)
        )
        self.pending: dict[int, TrackedCommand] = {}
        #: Recently failed commands by seq: an ack may still come (the MC republishes its
        #: last_command_seq at 5 Hz, so a link back up after the timeout shows it was accepted).
        self._failed: dict[int, TrackedCommand] = {}
        self._history = history
        #: Finished commands, newest last (bounded: the panel shows the recent ones).
        self.done: deque[TrackedCommand] = deque(maxlen=history)

    def _take_seq(self) -> int:
        seq = self._next_seq
        self._next_seq = 1 if seq >= SEQ_MAX else seq + 1
        return seq

    def new(
        self, command: str, target: str, now: float, *, expected: Iterable[str], altitude: float = 0.0
    ) -> TrackedCommand:
        """Register a command about to be sent; ``expected`` are the agents whose ack completes it."""
        if command not in COMMANDS:
            raise ValueError(f"unknown operator command {command!r}; known: {', '.join(COMMANDS)}")
        cmd = TrackedCommand(
            seq=self._take_seq(),
            command=command,
            target=target,
            altitude=altitude,
            sent_at=now,
            last_sent=now,
            expected=frozenset([target] if target else expected),
        )
        self.pending[cmd.seq] = cmd
        return cmd

    def observe(self, agent: str, last_command_seq: int, now: float) -> list[CommandUpdate]:
        """An ``mc_state_t`` from ``agent``: acknowledge the command it names, supersede older ones."""
        cmd = self.pending.get(last_command_seq)
        if cmd is None:
            late = self._failed.get(last_command_seq)
            return [] if late is None else self._late_ack(late, agent, now)
        if agent in cmd.acked or not (cmd.broadcast or cmd.target == agent):
            return []
        cmd.acked.add(agent)
        updates: list[CommandUpdate] = []
        for older in list(self.pending.values()):
            if older.seq < cmd.seq and agent in older.expected and agent not in older.settled:
                older.superseded.add(agent)
                updates.extend(self._maybe_complete(older, now, superseded_by=cmd))
        updates.extend(self._maybe_complete(cmd, now))
        return updates

    def _maybe_complete(
        self, cmd: TrackedCommand, now: float, superseded_by: TrackedCommand | None = None
    ) -> list[CommandUpdate]:
        if cmd.status is not Status.PENDING or not cmd.expected or cmd.missing:
            return []
        if not cmd.acked and superseded_by is not None:
            text = f"{cmd.label} #{cmd.seq} superseded by #{superseded_by.seq} (acknowledged first)"
            cmd.reason = f"superseded by #{superseded_by.seq}"
        else:
            text = f"{cmd.label} #{cmd.seq} acknowledged after {now - cmd.sent_at:.1f} s"
            if cmd.sends > 1:
                text += f" ({cmd.sends} sends)"
        self._finish(cmd, Status.ACKED, now)
        return [CommandUpdate(cmd, text)]

    def _late_ack(self, cmd: TrackedCommand, agent: str, now: float) -> list[CommandUpdate]:
        if agent in cmd.acked or not (cmd.broadcast or cmd.target == agent):
            return []
        cmd.acked.add(agent)
        if cmd.missing:
            return []
        self._failed.pop(cmd.seq, None)
        cmd.status = Status.ACKED
        cmd.reason = f"acked late ({now - cmd.sent_at:.1f} s)"
        return [
            CommandUpdate(
                cmd, f"{cmd.label} #{cmd.seq} acknowledged late, {now - cmd.sent_at:.1f} s after sending"
            )
        ]

    def _finish(self, cmd: TrackedCommand, status: Status, now: float) -> None:
        cmd.status = status
        cmd.done_at = now
        self.pending.pop(cmd.seq, None)
        self.done.append(cmd)
        if status is Status.FAILED:
            self._failed[cmd.seq] = cmd
            while len(self._failed) > self._history:
                del self._failed[next(iter(self._failed))]

    def tick(
        self,
        now: float,
        mc_state_of: Callable[[str], str | None] = lambda _a: None,
        is_stale: Callable[[str], bool] = lambda _a: False,
    ) -> tuple[list[TrackedCommand], list[CommandUpdate]]:
        """Commands due for a resend (the caller sends them, same seq) and failures to report."""
        resend: list[TrackedCommand] = []
        updates: list[CommandUpdate] = []
        for cmd in list(self.pending.values()):
            if now - cmd.sent_at >= self.timeout:
                if cmd.broadcast and not cmd.expected and cmd.acked:
                    # Nobody was known when it was sent: whoever acknowledged is the swarm.
                    self._finish(cmd, Status.ACKED, now)
                    updates.append(
                        CommandUpdate(
                            cmd, f"{cmd.label} #{cmd.seq} acknowledged by {len(cmd.acked)} agent(s)"
                        )
                    )
                    continue
                cmd.reason = self._failure_reason(cmd, mc_state_of, is_stale)
                self._finish(cmd, Status.FAILED, now)
                updates.append(
                    CommandUpdate(cmd, f"{cmd.label} #{cmd.seq} FAILED: {cmd.reason}", failed=True)
                )
            elif now - cmd.last_sent >= self.resend_interval:
                cmd.last_sent = now
                cmd.sends += 1
                resend.append(cmd)
        return resend, updates

    def _failure_reason(
        self, cmd: TrackedCommand, mc_state_of: Callable[[str], str | None], is_stale: Callable[[str], bool]
    ) -> str:
        missing = cmd.missing
        if cmd.broadcast and not cmd.expected:
            return f"no agent acknowledged in {self.timeout:g} s (none was known when it was sent)"
        why: list[str] = []
        for agent in missing[:3]:
            state = mc_state_of(agent)
            if is_stale(agent):
                why.append(f"{agent} is silent")
            elif applies(cmd.command, state) is False:
                allowed = "/".join(sorted(APPLIES_IN[cmd.command]))
                why.append(f"{agent} likely rejected it (MC {state}; {cmd.command} applies in {allowed})")
            else:
                why.append(f"{agent}: no ack (lost, or rejected)")
        more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
        head = f"{cmd.progress} acked; " if cmd.broadcast else ""
        return f"{head}no ack in {self.timeout:g} s after {cmd.sends} sends — " + "; ".join(why) + more

    def recent(self, n: int) -> list[TrackedCommand]:
        """Pending commands (oldest first) then the most recent finished ones: the panel's rows."""
        if n <= 0:
            return []
        pending = sorted(self.pending.values(), key=lambda c: c.seq)
        return (list(self.done) + pending)[-n:]

    def counts(self) -> dict[Status, int]:
        out = {s: 0 for s in Status}
        out[Status.PENDING] = len(self.pending)
        for cmd in self.done:
            out[cmd.status] += 1
        return out


@dataclass
class DirectionControl:
    """The operator's direction command (``direction_cmd_t``): azimuth, speed, on/off.

    Directions carry no acknowledgement (nothing in the agents echoes them), so instead of
    resend-until-ack the console repeats its latest direction every ``repeat_interval`` seconds:
    like a pilot's stick, it is a state, and a lost datagram is corrected within one period.
    """

    azimuth: float = 0.0
    speed: float = 1.0
    active: bool = False
    azimuth_step: float = 15.0
    speed_step: float = 0.5
    max_speed: float = 5.0
    repeat_interval: float = 1.0
    #: Where the latest direction went: an agent name, "" for all, None before the first send.
    target: str | None = None
    last_sent: float | None = None
    sends: int = 0

    def rotate(self, steps: int) -> None:
        self.azimuth = (self.azimuth + steps * self.azimuth_step) % 360.0
        self.active = True

    def change_speed(self, steps: int) -> None:
        self.speed = min(self.max_speed, max(0.0, round(self.speed + steps * self.speed_step, 3)))
        self.active = True

    def stop(self) -> None:
        self.active = False

    def sent(self, target: str, now: float) -> None:
        self.target = target
        self.last_sent = now
        self.sends += 1

    def due(self, now: float) -> bool:
        """Whether the latest direction should be repeated now."""
        return (
            self.target is not None
            and self.last_sent is not None
            and now - self.last_sent >= self.repeat_interval
        )

    def describe(self) -> str:
        if self.target is None:
            return "not sent"
        to = self.target or "ALL"
        state = "ACTIVE" if self.active else "stopped"
        return f"{state} {self.azimuth:03.0f}° {self.speed:.1f} m/s → {to}"
