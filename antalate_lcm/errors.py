"""Exceptions a user can meet, each carrying enough to say what to do next.

`AntalateError` is the root of every exception the package defines (``tests/test_layers.py`` checks
it), so ``except AntalateError`` (the CLI, the console) catches whatever antalate raises on purpose.
Exceptions defined elsewhere keep the standard base their callers already catch as a second base
(``AutopilotError(AntalateError, RuntimeError)``, ``ReplyError(AntalateError, ValueError)``).
"""

from __future__ import annotations


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
    """liblcm could not create an instance for a bus URL; says why when that is known."""

    def __init__(self, url: str, reason: str) -> None:
        self.url = url
        self.reason = reason
        super().__init__(f"cannot open the LCM bus {url!r}: {reason}")


class MulticastUnavailable(BusUnavailable):
    """LCM could not open a UDP multicast socket because this host has no route to the group.

    Raised only when the routing table says so (`antalate_lcm.lcm_url.open_failure`): its fix
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
    """A behavior or autopilot name that no entry point and no ``module:Class`` provides."""
