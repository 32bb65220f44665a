"""The Tello adapter's link: SDK commands out, replies and state packets in; djitellopy's or one in memory.

`TelloAdapter` needs four things of a link: send one datagram (``send``), the list its replies
arrive in (``replies``, which the adapter drains), the newest state packet (``state``: a new dict
object per packet, so identity says "new packet"), and ``open``/``close``. `DjitellopyLink` is a
Tello over Wi-Fi (UDP 8889/8890) through djitellopy; `MemoryLink` connects the adapter to a peer in
this process, as ``httpx.MockTransport`` stands in for the network: the peer is a callable that
answers an SDK command (or answers later with `MemoryLink.reply`) and pushes state lines in the
Tello's own text (`MemoryLink.push_state`), parsed as djitellopy parses them. The adapter takes a
`LinkOpener` (``TelloAdapter(params, link=...)``); the default opens a `DjitellopyLink`.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Mapping
from typing import Any, Protocol

from antalate_lcm.vehicles.base import AutopilotError
from antalate_lcm.vehicles.kit.memory import MemoryPipe
from antalate_lcm.vehicles.tello.params import Params

#: djitellopy (with av and numpy, 160 MB) is an extra, so a MAVLink or Crazyflie vehicle computer
#: does not carry it; only `DjitellopyLink.open` imports it, so a config validates without it.
DJITELLOPY_MISSING = (
    "the tello autopilot needs djitellopy, which is not installed: pip install 'antalate[tello]'"
)

#: The SDK's state fields that are integers and decimals (as djitellopy converts them); others
#: (``mpry``: ``x,y,z``) stay text.
INT_FIELDS = frozenset(
    (
        "mid",
        "x",
        "y",
        "z",
        "pitch",
        "roll",
        "yaw",
        "vgx",
        "vgy",
        "vgz",
        "templ",
        "temph",
        "tof",
        "h",
        "bat",
        "time",
    )
)
FLOAT_FIELDS = frozenset(("baro", "agx", "agy", "agz"))

#: Hosts with a live djitellopy link in this process: djitellopy keeps one reply queue per IP.
_HOSTS_IN_USE: set[str] = set()
_HOSTS_LOCK = threading.Lock()


def parse_state(line: str) -> dict[str, int | float | str]:
    """A state line (``pitch:0;roll:0;...;\\r\\n``) as a dict; a field that does not parse is left out."""
    state: dict[str, int | float | str] = {}
    for field in line.strip().split(";"):
        key, sep, text = field.partition(":")
        if not sep:
            continue
        try:
            state[key] = int(text) if key in INT_FIELDS else float(text) if key in FLOAT_FIELDS else text
        except ValueError:
            continue
    return state


class TelloLink(Protocol):
    """What `TelloAdapter` calls on its link (one adapter, one link; see the module docstring)."""

    #: Where the commands go, for messages (``192.168.10.1:8889``).
    where: str
    #: Where the state packets come in, for messages (``UDP 8890``).
    state_where: str

    def open(self) -> None:
        """Make the link usable; `AutopilotError` saying what to check when it cannot be."""

    def send(self, text: str) -> None:
        """One command datagram, no wait and no retry; `OSError` when it could not go."""

    def replies(self) -> list[bytes]:
        """The list replies are appended to, oldest first (the adapter pops and clears it)."""

    def state(self) -> Mapping[str, Any] | None:
        """The newest state packet (a new object for each packet), or None before the first."""

    def close(self) -> None:
        """Let go of the link (idempotent)."""


LinkOpener = Callable[[Params], TelloLink]


class DjitellopyLink:
    """A Tello over Wi-Fi through djitellopy's sockets (UDP 8889 commands, 8890 state), one per host."""

    def __init__(self, params: Params) -> None:
        self.host = params.host
        self._p = params
        self._tello: Any = None  # djitellopy.Tello once open
        self._owns_host = False
        self.where = f"{self.host}:8889"
        self.state_where = "UDP 8890"

    def open(self) -> None:
        try:
            from djitellopy import Tello
        except ImportError:
            raise AutopilotError(DJITELLOPY_MISSING) from None
        Tello.LOGGER.setLevel(self._p.djitellopy_log_level)
        # djitellopy prints through a handler of its own *and* propagates to the root logger, so
        # every line appeared twice; the application's logging configuration is the one to keep.
        Tello.LOGGER.removeHandler(Tello.HANDLER)
        self.where = f"{self.host}:{Tello.CONTROL_UDP_PORT}"
        self.state_where = f"UDP {Tello.STATE_UDP_PORT}"
        with _HOSTS_LOCK:
            if not self._owns_host and self.host in _HOSTS_IN_USE:
                raise AutopilotError(
                    f"another tello autopilot in this process already flies {self.host}: "
                    "djitellopy keeps one reply queue per IP, so each agent needs its own Tello"
                )
            _HOSTS_IN_USE.add(self.host)
            self._owns_host = True
        try:
            self._tello = Tello(self.host, retry_count=self._p.retry_count)
        except OSError as exc:
            self.close()
            raise AutopilotError(
                f"cannot bind UDP {Tello.CONTROL_UDP_PORT} for djitellopy ({exc}): another process on "
                "this machine talks to a Tello; run every Tello agent in one process "
                "(antalate agent tello-a.toml tello-b.toml)"
            ) from exc

    def send(self, text: str) -> None:
        tello = self._tello
        if tello is None:
            raise OSError("the link is closed")
        tello.send_command_without_return(text)

    def replies(self) -> list[bytes]:
        try:
            replies: list[bytes] = self._tello.get_own_udp_object()["responses"]
        except (KeyError, AttributeError, TypeError) as exc:  # closed under us
            raise AutopilotError(f"the link to the Tello at {self.host} is closed") from exc
        return replies

    def state(self) -> Mapping[str, Any] | None:
        """djitellopy's receiver replaces the per-drone dict on every packet: identity = packet."""
        tello = self._tello
        if tello is None:
            return None
        try:
            raw: Mapping[str, Any] | None = tello.get_current_state()
        except (KeyError, AttributeError):
            return None  # closed under us
        return raw or None

    def close(self) -> None:
        tello, self._tello = self._tello, None
        if tello is not None:
            tello.is_flying = False  # djitellopy's end()/__del__ would otherwise block on a land
            with contextlib.suppress(Exception):  # closing must not fail
                tello.end()  # drops this host from djitellopy's tables
            # end() runs again from Tello.__del__, whenever the object is collected; by then a new
            # link may have registered the same host, whose entry it would delete. Point this
            # object at no host so that second end() finds nothing to remove.
            tello.address = ("closed", tello.address[1])
        with _HOSTS_LOCK:
            if self._owns_host:
                _HOSTS_IN_USE.discard(self.host)
                self._owns_host = False


class MemoryLink:
    """A link to a peer in this process (`kit.MemoryPipe`): `handler` gets each command; answers come back as replies.

    `handler` returns the answer (``"ok"``, ``"85"``), or None for none now (``rc``; or a command the
    peer answers when it is done, with `reply`). State lines go in with `push_state`. All methods are
    thread-safe; `handler` runs on the sending thread and should not block for long.
    """

    def __init__(self, handler: Callable[[str], str | None], *, name: str = "memory") -> None:
        self._handler = handler
        # the peer's answers go straight into the live reply list, as djitellopy's receiver appends
        # them: the adapter polls the list it got from `replies`, so the pipe carries only our side
        self._pipe: MemoryPipe[str, None] = MemoryPipe(self._answer)
        self._lock = threading.Lock()
        self._replies: list[bytes] = []
        self._state: dict[str, int | float | str] | None = None
        self.where = f"{name} (in memory)"
        self.state_where = f"{name}'s state (in memory)"
        self.sent: list[str] = []  # every command, for tests

    @property
    def closed(self) -> bool:
        return self._pipe.closed

    def open(self) -> None:
        self._pipe.open()

    def send(self, text: str) -> None:
        self._pipe.send(text)

    def _answer(self, text: str) -> None:
        self.sent.append(text)
        answer = self._handler(text)
        if answer is not None:
            self.reply(answer)

    def replies(self) -> list[bytes]:
        if self.closed:
            raise AutopilotError(f"the link to {self.where} is closed")
        return self._replies

    def state(self) -> Mapping[str, Any] | None:
        with self._lock:
            return self._state

    def close(self) -> None:
        self._pipe.close()

    # -- the peer's side

    def reply(self, text: str) -> None:
        """An answer from the peer (dropped while closed, as a datagram to nobody)."""
        if not self.closed:
            self._replies.append(text.encode("utf-8"))

    def push_state(self, line: str) -> None:
        """A state packet from the peer, in the Tello's text (``pitch:0;roll:0;...;``)."""
        if self.closed:
            return
        parsed = parse_state(line)
        if parsed:
            with self._lock:
                self._state = parsed
