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
  (:mod:`antalate_lcm.zenoh_bus`), and a bridge never forwards to a bus a copy that came from that
  very bus through another bridge (two bridges on one LAN: whichever thread is first, no echo);
- bridges of one site (same ``[bridge] site``) elect the one that forwards Zenoh to their LAN (Zenoh
  liveliness tokens, lowest id alive), so a redundant gateway does not double messages on the LAN.

A rate cap per channel and direction (a thin uplink) keeps the newest message and sends it at the
next slot: a state topic always ends on its latest value, never on a dropped one.

The config is its own TOML file: ``[buses]`` as in an agent config, and ``[bridge]`` (docs/wan.md).
"""

from __future__ import annotations

import hashlib
import logging
import re
import sys
import threading
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from antalate_lcm.errors import ConfigError
from antalate_lcm.lcm_url import bus_url_problem
from antalate_lcm.zenoh_bus import BRIDGE_MARK

log = logging.getLogger("antalate.bridge")


# ---------------------------------------------------------------------------------------- config
class RateLimit(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    #: Channel regex (whole name), e.g. ``.*/TELEMETRY``.
    channel: str
    #: The bus the capped messages go to (the other direction is not capped).
    to: str
    #: Messages per second per channel at most; the newest waiting one is sent at each slot.
    rate: float = Field(gt=0)

    @field_validator("channel")
    @classmethod
    def _regex(cls, v: str) -> str:
        re.compile(v)
        return v


class BridgeSection(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    #: The two bus names (from [buses]) to join.
    between: list[str] = Field(min_length=2, max_length=2)
    #: Channel regexes (whole name) to forward; default every channel.
    channels: list[str] = Field(default_factory=lambda: [".*"])
    #: Channel regexes never forwarded (checked after ``channels``).
    exclude: list[str] = Field(default_factory=list)
    #: Seconds a forwarded message is remembered against echoes and duplicates.
    memory: float = Field(default=2.0, gt=0, le=60)
    #: Name of the network this bridge serves: bridges that join the *same* LAN to Zenoh (a
    #: redundant gateway) must share it, bridges of different sites must not. Empty: this bridge's
    #: own random id (safe: never mistakes another site's messages for its own).
    site: str = ""
    limit: list[RateLimit] = Field(default_factory=list)

    @field_validator("channels", "exclude")
    @classmethod
    def _regexes(cls, v: list[str]) -> list[str]:
        for pattern in v:
            re.compile(pattern)
        return v


class BridgeConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    buses: dict[str, str]
    bridge: BridgeSection

    @field_validator("buses")
    @classmethod
    def _urls(cls, v: dict[str, str]) -> dict[str, str]:
        problem = bus_url_problem(v)
        if problem is not None:
            raise ValueError(f"{problem[0]}: expected {problem[1]}")
        return v

    @model_validator(mode="after")
    def _known(self) -> BridgeConfig:
        a, b = self.bridge.between
        if a == b:
            raise ValueError(f"bridge.between: two different buses, not {a!r} twice")
        for name in (a, b):
            if name not in self.buses:
                raise ValueError(f"bridge.between: a bus declared in [buses], not {name!r}")
        if self.buses[a] == self.buses[b]:
            raise ValueError(f"bridge.between: {a} and {b} are the same bus ({self.buses[a]})")
        for i, lim in enumerate(self.bridge.limit):
            if lim.to not in (a, b):
                raise ValueError(f"bridge.limit[{i}].to: one of {a}, {b}, not {lim.to!r}")
        return self


def load_bridge_config(path: str | Path) -> BridgeConfig:
    """Read and check a bridge config; every mistake is a ConfigError naming the file and key."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - exercised only on 3.10
        import tomli as tomllib

    source = str(path)
    try:
        data = tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ConfigError(source, "", "no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "", f"not valid TOML ({exc})") from None
    try:
        return BridgeConfig.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err["loc"])
        msg = str(err["msg"]).removeprefix("Value error, ")
        named = re.match(r"([a-z_]+(?:\.[a-z_]+|\[\d+\]\.[a-z_]+)*): (.*)", msg, re.S)
        if named:  # our own checks name their key first
            key, msg = named.group(1), named.group(2)
        raise ConfigError(source, key, msg) from None
    except re.error as exc:
        raise ConfigError(source, "bridge", f"valid regular expressions ({exc})") from None


# ----------------------------------------------------------------------------------- pure logic
class Memory:
    """(channel, digest) pairs seen in the last ``window`` seconds. Not thread-safe."""

    def __init__(self, window: float) -> None:
        self.window = window
        self._seen: OrderedDict[bytes, float] = OrderedDict()

    @staticmethod
    def digest(channel: str, data: bytes) -> bytes:
        h = hashlib.blake2b(data, digest_size=16, person=b"antalate-bridge")
        h.update(channel.encode())
        return h.digest()

    def check_and_add(self, key: bytes, now: float) -> bool:
        """True (and remembered afresh) if ``key`` was seen within the window, else remember it."""
        while self._seen:
            oldest, t = next(iter(self._seen.items()))
            if now - t <= self.window:
                break
            del self._seen[oldest]
        seen = key in self._seen
        self._seen[key] = now
        self._seen.move_to_end(key)
        return seen

    def __len__(self) -> int:
        return len(self._seen)


class Throttle:
    """Newest-wins rate cap per channel: at most one message per ``1/rate`` s, the latest one."""

    def __init__(self, rate: float) -> None:
        self.interval = 1.0 / rate
        self._last: dict[str, float] = {}
        self._pending: dict[str, bytes] = {}
        #: Messages replaced by a newer one before their slot.
        self.superseded = 0

    def offer(self, channel: str, data: bytes, now: float) -> bool:
        """True: send now. False: kept as the channel's newest, sent by :meth:`due`."""
        last = self._last.get(channel)
        if last is None or now - last >= self.interval:
            self._last[channel] = now
            self._pending.pop(channel, None)
            return True
        if channel in self._pending:
            self.superseded += 1
        self._pending[channel] = data
        return False

    def due(self, now: float) -> list[tuple[str, bytes]]:
        out = []
        for channel in list(self._pending):
            if now - self._last[channel] >= self.interval:
                out.append((channel, self._pending.pop(channel)))
                self._last[channel] = now
        return out


@dataclass
class Direction:
    """What goes from one side to the other: the caps and the counters."""

    source: str
    dest: str
    limits: list[tuple[re.Pattern[str], Throttle]]
    forwarded: int = 0

    def throttle_for(self, channel: str) -> Throttle | None:
        for pattern, throttle in self.limits:
            if pattern.fullmatch(channel):
                return throttle
        return None


def origin_tag(name: str) -> bytes:
    """A short tag naming a bus of a site (the same on every bridge that joins that bus)."""
    return hashlib.blake2b(name.encode(), digest_size=6).hexdigest().encode()


# ------------------------------------------------------------------------------------------ I/O
def _open(url: str) -> Any:
    from antalate_lcm.bus import open_lcm, open_zenoh

    return open_zenoh(url) if url.startswith("zenoh://") else open_lcm(url)


class Bridge:
    """Two transports, one receive thread each; handlers forward under one lock (cheap, ordered)."""

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
        self._links: dict[str, Any] = {}
        self.directions: dict[str, Direction] = {}
        for src, dst in (self.names, self.names[::-1]):
            limits = [(re.compile(lim.channel), Throttle(lim.rate)) for lim in sec.limit if lim.to == dst]
            self.directions[src] = Direction(src, dst, limits)
        #: Origin tag of each side: a hash of the site and its URL (two bridges on one LAN share it).
        site = sec.site or self.id
        self.origin = {name: origin_tag(f"{site} {config.buses[name]}") for name in self.names}
        self.dropped_seen = 0
        self.dropped_same_origin = 0
        self.dropped_standby = 0
        #: Per LAN side: whether this bridge is the one (of those serving that LAN) that forwards to it.
        self.leader = dict.fromkeys(self.names, True)
        self.send_errors = 0
        self._threads: list[threading.Thread] = []

    def start(self) -> None:
        from antalate_lcm.zenoh_bus import ZenohLCM

        try:
            for name in self.names:
                self._links[name] = _open(self.config.buses[name])
        except Exception:
            self.close()
            raise
        for name in self.names:
            link = self._links[name]
            handler: Callable[..., None] = partial(self._on_message, name)
            if isinstance(link, ZenohLCM):
                sub = link.subscribe(".*", handler, remote_only=True, attachments=True)
            else:
                sub = link.subscribe(".*", handler)
            sub.set_queue_capacity(10_000)
        for zside, lside in (self.names, self.names[::-1]):
            zlink, llink = self._links[zside], self._links[lside]
            if isinstance(zlink, ZenohLCM) and not isinstance(llink, ZenohLCM):
                # Bridges serving one LAN (same site) elect the one that forwards to it: the lowest id alive.
                zlink.join_group(self.origin[lside].decode(), self.id, partial(self._on_members, lside))
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
        if not self._selected(channel):
            return
        direction = self.directions[source]
        forwarded = attachment is not None and attachment.startswith(BRIDGE_MARK)
        if forwarded and attachment.rpartition(b":")[2] == self.origin[direction.dest]:  # type: ignore[union-attr]
            self.dropped_same_origin += 1  # another bridge brought it from there: it is there already
            return
        now = time.monotonic()
        with self._lock:
            if self.memory.check_and_add(Memory.digest(channel, data), now):
                self.dropped_seen += 1
                return
            if not self.leader[direction.dest]:
                # Another bridge of this site forwards it; remembered above, so its copy on the LAN
                # is not sent back to Zenoh from here.
                self.dropped_standby += 1
                return
            throttle = direction.throttle_for(channel)
            if throttle is not None and not throttle.offer(channel, data, now):
                return
            self._send(direction, channel, data)

    def _send(self, direction: Direction, channel: str, data: bytes) -> None:
        """Publish on the destination (caller holds the lock: the copy must be remembered first)."""
        link = self._links[direction.dest]
        # Remembered before it goes out: the looped-back copy must find it.
        self.memory.check_and_add(Memory.digest(channel, data), time.monotonic())
        try:
            if hasattr(link, "connected"):
                link.publish(channel, data, attachment=self.mark + b":" + self.origin[direction.source])
            else:
                link.publish(channel, data)
        except OSError as exc:
            self.send_errors += 1
            if self.send_errors in (1, 10, 100) or self.send_errors % 1000 == 0:
                log.warning(
                    "bridge %s: cannot send %s on %s (%s); %d so far",
                    self.id,
                    channel,
                    direction.dest,
                    exc,
                    self.send_errors,
                )
            return
        direction.forwarded += 1

    def _run(self, name: str) -> None:
        link = self._links[name]
        direction = self.directions[name]  # what this side sends out; its caps are flushed here
        while not self._stop.is_set():
            try:
                link.handle_timeout(20)
            except OSError as exc:
                if not self._stop.is_set():
                    log.error("bridge %s: bus %s stopped delivering: %s", self.id, name, exc)
                return
            if direction.limits:
                now = time.monotonic()
                with self._lock:
                    for _pattern, throttle in direction.limits:
                        for channel, data in throttle.due(now):
                            self._send(direction, channel, data)

    def stats(self) -> dict[str, int]:
        a, b = self.names
        return {
            f"{a}->{b}": self.directions[a].forwarded,
            f"{b}->{a}": self.directions[b].forwarded,
            "not_forwarded_seen": self.dropped_seen,
            "not_forwarded_same_origin": self.dropped_same_origin,
            "not_forwarded_standby": self.dropped_standby,
            "send_errors": self.send_errors,
        }

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2)
        for link in self._links.values():
            if hasattr(link, "close"):
                link.close()
        self._links.clear()


__all__: Sequence[str] = ["Bridge", "BridgeConfig", "Memory", "Throttle", "load_bridge_config"]
