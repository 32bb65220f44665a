"""The rule by which the processes of one ``antalate run --speed --processes P`` agree on time.

Pure logic, no I/O (the sockets are in :mod:`antalate_lcm.runtime.time_coordinator`), so it is
tested on its own. Each process (the operator's, index 0, and each agent process) runs its loop on
a :class:`~antalate_lcm.core.simclock.SimClock` at the same simulated time ``t``; when it has nothing
left to do at ``t`` it *reports*: the time of its next timer and every message it published since
its last report on the buses that cross processes, in publish order. Once every process has
reported (every one idle at ``t``, so none can still send at ``t``):

- if any report carried messages another process subscribes to (its :class:`Interest`), each
  such process is handed them, ordered by process index and then publish order, and delivers them
  still at ``t`` (what it sends in answer is reported next, still at ``t``: a round of the same
  instant);
- else nothing is in flight: time moves to the earliest next timer of all (the processes with a
  timer then are woken; the others move when next woken).

So no process runs a timer at ``t' > t`` while another still has work at ``t``, and a message sent
at ``t`` reaches every other process before it moves past ``t``. Messages travel only through the
reports (never on a socket a process reads at its own pace), and a round's order depends only on
what each process sent: with a seed, the run is as deterministic as one process's.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

#: A message in a report: bus name length, channel length, data length; then the three.
_MESSAGE = struct.Struct("<BHI")


@dataclass(frozen=True)
class Report:
    """One process idle at the current simulated time."""

    #: Simulated time of its next timer (``math.inf``: none).
    next_due: float
    #: Its messages since its last report, encoded (:func:`encode_message`), in publish order.
    messages: bytes = b""


@dataclass(frozen=True)
class Deliver:
    """Messages to deliver at the current time: ``batches[i]`` for process ``i`` (the others'; a
    process given none is not woken: it would only report the same again)."""

    batches: tuple[bytes, ...]


@dataclass(frozen=True)
class Advance:
    """Nothing in flight: time moves to ``t``. Only the processes with a timer due then are woken
    (``woken``); the others move to ``t`` when they are next woken (a delivery says its time)."""

    t: float
    woken: tuple[int, ...]


@dataclass
class Interest:
    """What one process subscribes to on the buses that cross processes: the messages worth
    handing it (another agent process's MC states and telemetry are not, unless a behavior asks)."""

    #: (bus, channel) subscribed exactly.
    exact: set[tuple[str, str]] = field(default_factory=set)
    #: (bus, pattern) subscribed by regular expression (the recorder's ``.*``).
    patterns: list[tuple[str, re.Pattern[str]]] = field(default_factory=list)
    _memo: dict[tuple[str, str], bool] = field(default_factory=dict, repr=False)

    def add(self, bus: str, channel: str, regex: bool) -> None:
        if regex:
            self.patterns.append((bus, re.compile(channel)))
        else:
            self.exact.add((bus, channel))
        self._memo.clear()

    def wants(self, bus: str, channel: str) -> bool:
        key = (bus, channel)
        known = self._memo.get(key)
        if known is None:
            known = key in self.exact or any(b == bus and p.fullmatch(channel) for b, p in self.patterns)
            if len(self._memo) < 100_000:  # bounded: channel names come from the nodes
                self._memo[key] = known
        return known


def encode_interest(subscriptions: Iterable[tuple[str, str, bool]]) -> bytes:
    """Subscriptions (bus, channel, regex) as a process sends them: one per line."""
    return "".join(f"{bus}\t{int(regex)}\t{channel}\n" for bus, channel, regex in subscriptions).encode()


def add_interest(interest: Interest, blob: bytes) -> None:
    """Add the subscriptions of ``blob`` (:func:`encode_interest`) to ``interest``."""
    for line in blob.decode().splitlines():
        bus, regex, channel = line.split("\t", 2)
        interest.add(bus, channel, regex == "1")


def decide(
    reports: Sequence[Report | None], interests: Sequence[Interest] | None = None
) -> Deliver | Advance | None:
    """What the processes do next, given each one's report (None: it still works, or has not
    joined yet) and what each subscribes to (None: everything); None: wait for the missing
    reports."""
    if not reports or any(r is None for r in reports):
        return None
    done = [r for r in reports if r is not None]
    if any(r.messages for r in done):
        batches = _batches(done, interests)
        if any(batches):
            return Deliver(batches)
    t = min(r.next_due for r in done)
    # No timer anywhere and nothing in flight: only another thread (a stop) can give work now.
    if math.isinf(t):
        return None
    return Advance(t, tuple(i for i, r in enumerate(done) if r.next_due <= t))


def _batches(done: Sequence[Report], interests: Sequence[Interest] | None) -> tuple[bytes, ...]:
    """For each process, the others' messages it wants, by process index and publish order."""
    n = len(done)
    if interests is None:
        return tuple(b"".join(o.messages for j, o in enumerate(done) if j != i) for i in range(n))
    out: list[list[bytes]] = [[] for _ in range(n)]
    for j, report in enumerate(done):
        if not report.messages:
            continue
        for bus, channel, raw in split_messages(report.messages):
            for i in range(n):
                if i != j and interests[i].wants(bus, channel):
                    out[i].append(raw)
    return tuple(b"".join(parts) for parts in out)


def woken(decision: Deliver | Advance) -> tuple[int, ...]:
    """The processes a decision wakes (each reports again once it is idle)."""
    if isinstance(decision, Advance):
        return decision.woken
    return tuple(i for i, batch in enumerate(decision.batches) if batch)


def remaining(reports: Sequence[Report | None], decision: Deliver | Advance) -> list[Report | None]:
    """The reports that still hold after ``decision``: those of the processes it does not wake,
    their messages handed on."""
    awake = set(woken(decision))
    return [None if i in awake or r is None else Report(r.next_due) for i, r in enumerate(reports)]


def merge(old: Report | None, new: Report) -> Report:
    """A process that reported and then had work again (another thread's call, never a timer's)
    reports anew: its messages add up, its next timer is the new one."""
    return new if old is None else Report(new.next_due, old.messages + new.messages)


def encode_message(bus: str, channel: str, data: bytes) -> bytes:
    """One message as reports carry it."""
    b, c = bus.encode(), channel.encode()
    return _MESSAGE.pack(len(b), len(c), len(data)) + b + c + data


def split_messages(blob: bytes) -> Iterator[tuple[str, str, bytes]]:
    """The (bus, channel, message as encoded) of each message in ``blob``, in order."""
    view, i, n = memoryview(blob), 0, len(blob)
    size = _MESSAGE.size
    while i < n:
        lb, lc, ld = _MESSAGE.unpack_from(blob, i)
        start = i
        i += size
        bus = bytes(view[i : i + lb]).decode()
        i += lb
        channel = bytes(view[i : i + lc]).decode()
        i += lc + ld
        yield bus, channel, blob[start:i]


def decode_messages(blob: bytes) -> Iterator[tuple[str, str, bytes]]:
    """The (bus, channel, data) of each message in ``blob``, in order."""
    view, i, n = memoryview(blob), 0, len(blob)
    size = _MESSAGE.size
    while i < n:
        lb, lc, ld = _MESSAGE.unpack_from(blob, i)
        i += size
        bus = bytes(view[i : i + lb]).decode()
        i += lb
        channel = bytes(view[i : i + lc]).decode()
        i += lc
        yield bus, channel, bytes(view[i : i + ld])
        i += ld


def pace(speed: float, real0: float, sim0: float, t: float, real_now: float) -> float:
    """Real seconds to wait before time moves to ``t`` so it runs at most ``speed`` times real time
    since (``real0``, ``sim0``); 0 at ``max`` and for a run that has fallen behind."""
    if math.isinf(speed):
        return 0.0
    return max(0.0, real0 + (t - sim0) / speed - real_now)
