"""Exceptions a user can meet, each carrying enough to say what to do next.

`AntalateError` is the root of every exception the package defines (``tests/architecture/test_layers.py`` checks
it), so ``except AntalateError`` (the CLI, the console) catches whatever antalate raises on purpose.
They are all defined here, as httpx keeps its exceptions in one module, so the whole hierarchy reads in
one place; the module that raises one re-exports it under its old name (``antalate_lcm.vehicles.
AutopilotError``, ``antalate_lcm.base.strict.StrictError``, …), which is where docs and behaviors import it
from. An exception a caller used to catch by a standard base keeps that base as a second one
(``AutopilotError(AntalateError, RuntimeError)``, ``ReplyError(AntalateError, ValueError)``). Private
control flow that never leaves its module (``_KeyedError``, ``_TooLarge``, the Tello's ``_Preempted``)
stays beside the code that raises and catches it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from antalate_lcm.base.deprecation import renamed_names


class AntalateError(Exception):
    """Base of every error antalate raises on purpose (the CLI prints these without a traceback)."""


class ConfigError(AntalateError):
    """An invalid config file: names the file, the key and what was expected."""

    def __init__(self, file: str, key: str, expected: str) -> None:
        self.file = file
        self.key = key
        self.expected = expected
        where = f"{file}: {key}" if key else file
        super().__init__(f"invalid config {where}: {expected}")


class BusUnavailable(AntalateError):
    """A bus URL could not be opened (by liblcm or antalate's own transport); says why when that is known."""

    def __init__(self, url: str, reason: str) -> None:
        self.url = url
        self.reason = reason
        super().__init__(f"cannot open the LCM bus {url!r}: {reason}")


class InvalidBusUrl(BusUnavailable, ValueError):
    """A bus URL that breaks its transport's rules (`antalate_lcm.transports.transport_for`); the
    reason says what was expected."""


class UnknownTransport(InvalidBusUrl):
    """A bus URL whose scheme no transport serves; the reason names the schemes that are known."""


class MulticastUnavailable(BusUnavailable):
    """LCM could not open a UDP multicast socket because this host has no route to the group.

    Raised only when the routing table says so (`antalate_lcm.transports.udpm.Udpm.failure`): its fix
    would be the wrong advice for a bad URL or a busy socket.
    """

    def __init__(self, url: str) -> None:
        super().__init__(
            url,
            "this host has no route for multicast (224.0.0.0/4).\n"
            "  fix, for a single host with no network:  sudo ip route add 224.0.0.0/4 dev lo\n"
            "  (and, if lo is down: sudo ip link set lo up)\n"
            "  on a LAN, route multicast to the interface that faces the other hosts, e.g.\n"
            "      sudo ip route add 224.0.0.0/4 dev eth0\n"
            '  or run every node in one process on the in-memory bus: set the bus URL to "memq://".',
        )


class PluginNotFound(AntalateError):
    """A behavior or vehicle adapter name that no entry point and no ``module:Class`` provides."""


# Vehicles (antalate_lcm.vehicles)


class AutopilotError(AntalateError, RuntimeError):
    """A command the vehicle refused, did not acknowledge, or cannot perform in its current state."""


class UnknownAdapterError(PluginNotFound, LookupError):
    """The configured ``[hlc] autopilot`` matches no registered vehicle adapter, or cannot be loaded.

    A `PluginNotFound` (the CLI prints it without a traceback) and a `LookupError`.
    """


class LinkClosed(AntalateError, ConnectionError):
    """The link was closed by our side (`MavLink.close`)."""


class PeerClosed(AntalateError, ConnectionError):
    """The other end closed a stream link (pymavlink would otherwise just keep returning nothing)."""


# Configuration and plugins


class StrictError(AntalateError, ValueError):
    """One invalid value: ``key`` is the dotted path inside the validated table ('' = the table)."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}" if key else message)
        self.key = key
        self.message = message


# Nodes and behaviors


class InsecureBus(AntalateError):
    """A node would consume an internal topic from a network-reachable bus with no swarm key."""


class BehaviorError(AntalateError):
    """Raise this for an expected failure; its message alone is reported (no exception type name).

    E.g. ``raise BehaviorError("ffmpeg not found: apt-get install ffmpeg")`` shows up in the
    operator console as exactly that, which is more useful than ``FileNotFoundError: [Errno 2] ...``.
    """


# The station and its clients (the OSC, an operator's StationClient)


class ServerProblem(AntalateError):
    """One failed exchange with the station (down, timeout, wrong status, oversized or invalid reply)."""

    def __init__(self, text: str, retry_after: float = 0.0) -> None:
        super().__init__(text)
        self.retry_after = retry_after


class ReplyError(AntalateError, ValueError):
    """A reply the OSC will not act on; the message says what was wrong with it."""


class StationDBError(AntalateError):
    """The database file cannot be used (unreadable, from a newer antalate, not a station database)."""


class UnknownTarget(AntalateError, LookupError):
    """A command addressed to a name or id the station has never seen."""


class Refused(AntalateError):
    """A request the station turns down: an HTTP status, a sentence, and for 429 when to retry."""

    def __init__(self, status: int, detail: str, retry_after: float | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.retry_after = retry_after


class StationClientError(AntalateError):
    """The station refused a request: the HTTP status and its one-sentence reason."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(f"station answered {status}: {detail}")
        self.status = status
        self.detail = detail


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
