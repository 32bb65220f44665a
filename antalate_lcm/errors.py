"""Exceptions a user can meet, each carrying enough to say what to do next."""

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


class MulticastUnavailable(AntalateError):
    """LCM could not open a UDP multicast socket, nearly always for lack of a multicast route."""

    def __init__(self, url: str) -> None:
        self.url = url
        super().__init__(
            f"cannot open the LCM bus {url!r}: this host has no route for multicast (224.0.0.0/4).\n"
            "  fix, for a single host with no network:  sudo ip route add 224.0.0.0/4 dev lo\n"
            "  (and, if lo is down: sudo ip link set lo up)\n"
            "  on a LAN, route multicast to the interface that faces the other hosts, e.g.\n"
            "      sudo ip route add 224.0.0.0/4 dev eth0\n"
            "  or run every node in one process on the in-memory bus: set the bus URL to \"memq://\"."
        )


class PluginNotFound(AntalateError):
    """A behavior or autopilot name that no entry point and no ``module:Class`` provides."""
