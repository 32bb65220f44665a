"""The ``tcpq://`` transport: liblcm's TCP queue, every message through an LCM TCP queue server."""

from __future__ import annotations

from antalate_lcm.transports.base import HOSTNAME, LcmUrl, Transport, port_problem

DEFAULT_TCPQ = "127.0.0.1:7700"


class Tcpq(Transport):
    """liblcm's ``lcm_tcpq.c``: ``HOST:PORT`` of the server (127.0.0.1:7700 when empty), no options."""

    scheme = "tcpq"

    @classmethod
    def check(cls, u: LcmUrl) -> LcmUrl:
        network = u.network or DEFAULT_TCPQ
        host, sep, port = network.partition(":")
        if not HOSTNAME.fullmatch(host):
            raise ValueError(f"a server HOST:PORT (an IPv4 address or a host name), not {network!r}")
        problem = port_problem(port, "after the host") if sep else None
        if problem:
            raise ValueError(problem)
        return LcmUrl(u.url, u.scheme, u.network, u.options, host, int(port) if sep else 7700)
