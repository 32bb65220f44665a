"""``antalate bridge``: forward chosen channels between two buses, e.g. a site's LAN and a Zenoh bus.

A bridge forwards the bytes as they are -- it never decodes, re-encodes or re-signs -- so the MAC
and the replay guard hold end to end. It must never loop and never duplicate, and it cannot mark a
message (the MAC covers every byte), so it remembers what it has carried:

- every message it receives on either side is remembered for :attr:`BridgeConfig.memory` seconds
  by (channel, hash of the bytes); a message it already remembers is not forwarded. That stops the
  copy it published itself coming back (multicast loops back to its own socket) and the copy a second
  bridge already carried;
- on Zenoh it also subscribes to remote samples only and marks what it puts (attachment
  ``antalate-bridge:ID:ORIGIN``, ORIGIN a hash of ``[bridge] site`` and the bus the message came
  from), so a Zenoh
  subscriber receives one copy when two bridges forward the same message
  (:mod:`antalate_lcm.transports.zenoh`), and a bridge never forwards to a bus a copy that came from that
  very bus through another bridge (two bridges on one LAN: whichever thread is first, no echo);
- bridges of one site (same ``[bridge] site``) elect the one that forwards Zenoh to their LAN (Zenoh
  liveliness tokens, lowest id alive), so a redundant gateway does not double messages on the LAN.

A rate cap per channel and direction (a thin uplink) keeps the newest message and sends it at the
next slot: a state topic always ends on its latest value, never on a dropped one.

Whoever reaches the router or the LAN must not be able to stop, stall or amplify it (issue 29):

- every message that cannot be forwarded (a channel LCM cannot carry, over its size limit, an error
  of the destination) is counted by reason, logged once per reason and direction per 10 s, and
  dropped; nothing one message does ends a direction's thread;
- sizes are limited per channel and direction (``max_size``, ``[[bridge.size]]``), checked on the
  first fragment that names the size (the LAN is read from antalate's own socket, reassembled by
  :class:`~antalate_lcm.transports.datagram.Reassembler`) and by Zenoh itself before it reassembles; a
  message is delivered only when its fragments carried all its bytes, so bytes out <= bytes in;
- what it remembers is bounded in time *and* count (seen messages, rate-cap slots, Zenoh publishers),
  and each direction has its own thread, queue and budget: sending never holds the lock the other
  direction needs;
- with ``[security] swarm_key``, the election counts only liveliness tokens signed with it.

The config is its own TOML file: ``[buses]`` as in an agent config, and ``[bridge]`` (docs/wan.md).
"""

from __future__ import annotations

import logging
import re
import select
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

from antalate_lcm.apps.bridge_config import BridgeConfig, load_bridge_config
from antalate_lcm.apps.bridge_policy import DROP_REASONS, Direction, Memory, Throttle, origin_tag
from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.transports import Connection, transport_for
from antalate_lcm.transports.datagram import Reassembler, channel_problem
from antalate_lcm.transports.udpm import Udpm
from antalate_lcm.transports.zenoh import BRIDGE_MARK, ZenohLCM
from antalate_lcm.wire.security import MemberProof

log = logging.getLogger("antalate.bridge")


class _LanConnection:
    """A ``udpm://`` LAN: read from antalate's own socket (sizes checked on the first fragment, before
    any buffer is allocated), sent by liblcm (whose receive thread never starts: nothing subscribes)."""

    def __init__(self, transport: Udpm, size_limit: Callable[[str], int], largest: int) -> None:
        reassembler = Reassembler(max_message_size=largest, size_limit=size_limit)
        self.receiver = transport.receiver(reassembler)
        try:
            self._lcm = transport.open()
        except Exception:
            self.receiver.close()
            raise
        self._handler: Callable[[str, bytes], None] = lambda channel, data: None
        self.closed = False
        self._counted = (0, 0)

    def take_drops(self) -> tuple[int, int]:
        """(oversize, damaged) datagrams the reassembler dropped since the last call."""
        r = self.receiver.reassembler
        now = (r.oversize, r.dropped + r.evicted)
        before, self._counted = self._counted, now
        return now[0] - before[0], now[1] - before[1]

    def subscribe(self, handler: Callable[[str, bytes], None]) -> None:
        self._handler = handler

    def publish(self, channel: str, data: bytes) -> None:
        self._lcm.publish(channel, data)

    def handle_timeout(self, timeout_ms: int) -> int:
        readable, _, _ = select.select([self.receiver.fileno()], [], [], timeout_ms / 1000)
        return self.receiver.drain(self._handler, 256) if readable else 0

    def close(self) -> None:
        self.closed = True
        self.receiver.close()


def _open(url: str, direction_in: Direction, largest: int) -> _LanConnection | Connection:
    transport = transport_for(url)
    if isinstance(transport, Udpm):
        return _LanConnection(transport, direction_in.size_limit, largest)
    # Zenoh drops a larger message itself, before reassembling it (+ room for key and attachment);
    # memq://, file://: nobody outside the process writes there.
    return transport.open(max_message_size=largest + 4096)


class Bridge:
    """Two transports, one receive thread each; a short lock orders what both directions remember."""

    def __init__(self, config: BridgeConfig, *, bridge_id: str | None = None) -> None:
        self.config = config
        self.id = bridge_id or uuid.uuid4().hex[:12]
        self.mark = BRIDGE_MARK + self.id.encode()
        sec = config.bridge
        self._select = [re.compile(p) for p in sec.channels]
        self._exclude = [re.compile(p) for p in sec.exclude]
        self.memory = Memory(sec.memory)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.names: tuple[str, str] = (sec.between[0], sec.between[1])
        self._connections: dict[str, Any] = {}
        self.directions: dict[str, Direction] = {}
        for src, dst in (self.names, self.names[::-1]):
            limits = [(re.compile(lim.channel), Throttle(lim.rate)) for lim in sec.limit if lim.to == dst]
            sizes = [(re.compile(s.channel), s.max) for s in sec.size if s.to == dst]
            self.directions[src] = Direction(src, dst, limits, sizes, sec.max_size)
        #: Origin tag of each side: a hash of the site and its URL (two bridges on one LAN share it).
        site = sec.site or self.id
        self.origin = {name: origin_tag(f"{site} {config.buses[name]}") for name in self.names}
        #: Per LAN side: whether this bridge is the one (of those serving that LAN) that forwards to it.
        self.leader = dict.fromkeys(self.names, True)
        self.send_errors = 0
        self._threads: list[threading.Thread] = []
        #: Per side: whether it is a Zenoh bus (what it takes: attachments, any channel name).
        self._zenoh: dict[str, bool] = {}
        self._log = RateLimitedLog(log, period=10.0)
        keys = config.security
        self._proof = (
            MemberProof((keys.swarm_key, *keys.previous_keys), keys.window) if keys.swarm_key else None
        )

    def start(self) -> None:
        try:
            for name in self.names:
                direction_in = self.directions[name]
                largest = max(direction_in.largest, self.directions[direction_in.dest].largest)
                self._connections[name] = _open(self.config.buses[name], direction_in, largest)
        except Exception:
            self.close()
            raise
        self._zenoh = {name: isinstance(conn, ZenohLCM) for name, conn in self._connections.items()}
        for name in self.names:
            conn = self._connections[name]
            handler: Callable[..., None] = partial(self._on_message, name)
            if isinstance(conn, ZenohLCM):
                conn.subscribe(".*", handler, remote_only=True, attachments=True).set_queue_capacity(10_000)
            elif isinstance(conn, _LanConnection):
                conn.subscribe(handler)  # the kernel's socket buffer is its queue
            else:
                conn.subscribe(".*", handler).set_queue_capacity(10_000)
        for zside, lside in (self.names, self.names[::-1]):
            zconn, lconn = self._connections[zside], self._connections[lside]
            if isinstance(zconn, ZenohLCM) and not isinstance(lconn, ZenohLCM):
                if self._proof is None:
                    log.warning(
                        "bridge %s: no [security] swarm_key: any client of the Zenoh router can take "
                        "over the election of the bridges of this site (docs/wan.md)",
                        self.id,
                    )
                # Bridges serving one LAN (same site) elect the one that forwards to it: the lowest id alive.
                zconn.join_group(
                    self.origin[lside].decode(), self.id, partial(self._on_members, lside), self._proof
                )
        for name in self.names:
            t = threading.Thread(target=self._run, args=(name,), name=f"bridge {name}", daemon=True)
            t.start()
            self._threads.append(t)
        log.info(
            "bridge %s: %s (%s) <-> %s (%s)",
            self.id,
            self.names[0],
            self.config.buses[self.names[0]],
            self.names[1],
            self.config.buses[self.names[1]],
        )

    def _on_members(self, side: str, members: frozenset[str]) -> None:
        leader = min(members) == self.id
        if leader != self.leader[side]:
            log.info(
                "bridge %s: %s forwarding to %s (bridges of this site alive: %s)",
                self.id,
                "now" if leader else "no longer",
                side,
                ", ".join(sorted(members)),
            )
        self.leader[side] = leader

    def _selected(self, channel: str) -> bool:
        return any(p.fullmatch(channel) for p in self._select) and not any(
            p.fullmatch(channel) for p in self._exclude
        )

    def _on_message(self, source: str, channel: str, data: bytes, attachment: bytes | None = None) -> None:
        """Whatever one message holds, it is forwarded or counted and dropped: never an exception."""
        direction = self.directions[source]
        try:
            self._forward(direction, channel, data, attachment)
        except Exception as exc:  # noqa: BLE001 - one message must never end a direction
            self._drop(direction, "error", channel, f"{type(exc).__name__}: {exc}")

    def _drop(self, direction: Direction, reason: str, channel: str, detail: str, count: int = 1) -> None:
        n = direction.dropped.get(reason, 0) + count
        direction.dropped[reason] = n
        self._log.log(
            (direction.source, reason),
            logging.WARNING,
            "bridge %s: dropped a message from %s to %s because %s (%s; channel %r): %d so far",
            self.id,
            direction.source,
            direction.dest,
            DROP_REASONS[reason],
            detail,
            channel[:80],
            n,
        )

    def _forward(self, direction: Direction, channel: str, data: bytes, attachment: bytes | None) -> None:
        direction.bytes_in += len(data)
        if not self._selected(channel):
            direction.not_selected += 1
            return
        if not self._zenoh[direction.dest]:
            problem = channel_problem(channel)
            if problem is not None:
                self._drop(direction, "bad_channel", channel, problem)
                return
        limit = direction.size_limit(channel)
        if len(data) > limit:
            self._drop(direction, "oversize", channel, f"{len(data)} bytes, limit {limit}")
            return
        forwarded = attachment is not None and attachment.startswith(BRIDGE_MARK)
        if forwarded and attachment.rpartition(b":")[2] == self.origin[direction.dest]:  # type: ignore[union-attr]
            direction.same_origin += 1  # another bridge brought it from there: it is there already
            return
        now = time.monotonic()
        with self._lock:
            if self.memory.check_and_add(Memory.digest(channel, data), now):
                direction.seen += 1
                return
            if not self.leader[direction.dest]:
                # Another bridge of this site forwards it; remembered above, so its copy on the LAN
                # is not sent back to Zenoh from here.
                direction.standby += 1
                return
            throttle = direction.throttle_for(channel)
            if throttle is not None and not throttle.offer(channel, data, now):
                return
        # Remembered above before it goes out (the looped-back copy finds it); sent without the lock,
        # so a slow destination never holds up the other direction.
        self._send(direction, channel, data)

    def _send(self, direction: Direction, channel: str, data: bytes) -> None:
        conn = self._connections[direction.dest]
        try:
            if self._zenoh[direction.dest]:
                conn.publish(channel, data, attachment=self.mark + b":" + self.origin[direction.source])
            else:
                conn.publish(channel, data)
        except Exception as exc:  # noqa: BLE001 - a dead connection or a refused message: counted, never fatal
            self.send_errors += 1
            self._drop(direction, "send_error", channel, f"{type(exc).__name__}: {exc}")
            return
        direction.forwarded += 1
        direction.bytes_out += len(data)

    def _run(self, name: str) -> None:
        conn = self._connections[name]
        direction = self.directions[name]  # what this side sends out; its caps are flushed here
        pruned = time.monotonic()
        while not self._stop.is_set():
            try:
                conn.handle_timeout(20)
            except Exception as exc:  # noqa: BLE001 - the loop survives; only a closed connection ends it
                if self._stop.is_set() or getattr(conn, "closed", False):
                    return
                self._log.log(
                    (name, "receive"),
                    logging.ERROR,
                    "bridge %s: receiving from %s failed: %s: %s",
                    self.id,
                    name,
                    type(exc).__name__,
                    exc,
                )
                self._stop.wait(0.1)
            if isinstance(conn, _LanConnection):
                oversize, damaged = conn.take_drops()
                for reason, n in (("oversize", oversize), ("damaged", damaged)):
                    if n:
                        self._drop(direction, reason, "", f"{n} datagrams, found when reassembling", n)
            now = time.monotonic()
            due: list[tuple[str, bytes]] = []
            with self._lock:
                for _pattern, throttle in direction.limits:
                    due.extend(throttle.due(now))
                if now - pruned >= 0.5:  # what was remembered goes when it is old, also when all is quiet
                    pruned = now
                    self.memory.prune(now)
                    for _pattern, throttle in direction.limits:
                        throttle.prune(now)
            for channel, data in due:
                self._send(direction, channel, data)

    def stats(self) -> dict[str, int]:
        a, b = self.names
        out = {
            f"{a}->{b}": self.directions[a].forwarded,
            f"{b}->{a}": self.directions[b].forwarded,
            "not_forwarded_seen": sum(d.seen for d in self.directions.values()),
            "not_forwarded_same_origin": sum(d.same_origin for d in self.directions.values()),
            "not_forwarded_standby": sum(d.standby for d in self.directions.values()),
            "send_errors": self.send_errors,
        }
        out["election_tokens_ignored"] = sum(
            conn.ignored_tokens for name, conn in self._connections.items() if self._zenoh.get(name)
        )
        for d in self.directions.values():
            out[f"not_selected {d.source}->{d.dest}"] = d.not_selected
            for reason, n in sorted(d.dropped.items()):
                out[f"dropped_{reason} {d.source}->{d.dest}"] = n
            out[f"bytes {d.source}->{d.dest} in"] = d.bytes_in
            out[f"bytes {d.source}->{d.dest} out"] = d.bytes_out
        return out

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2)
        for conn in self._connections.values():
            if hasattr(conn, "close"):
                conn.close()
        self._connections.clear()


__all__: Sequence[str] = [
    "Bridge",
    "BridgeConfig",
    "Direction",
    "Memory",
    "Throttle",
    "load_bridge_config",
    "origin_tag",
]
