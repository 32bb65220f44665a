"""``antalate foxglove CONFIG``: the swarm live in Foxglove, over the Foxglove WebSocket protocol.

Every message heard on the bus is served on the channels, with the schemas, an MCAP file of the same
flight has (``json_view``): the Map panel shows ``{agent}/location``, the 3D panel ``swarm/scene``, a
Raw Messages or Plot panel any ``{agent}/TELEMETRY`` field. The server is foxglove-sdk's (the
``foxglove`` extra), run with no capability a client could use to write: it publishes, never
accepts a client's message, service call or parameter, so nothing reaches the swarm through it.

What it shows is still the swarm's picture (positions, states, batteries, commands), and the protocol
has no credential a server could check; so, as the web console refuses to serve beyond loopback with
no sign-in (docs/security.md), this server binds to loopback and serves beyond it only when
``--no-auth`` says so, with a warning. From another machine, prefer an SSH tunnel to loopback.
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading
import time
from types import FrameType
from typing import Any

from antalate_lcm.base.errors import AntalateError
from antalate_lcm.wire.json_view import ChannelSpec, JsonView

log = logging.getLogger("antalate.foxglove")

FOXGLOVE_MISSING = (
    "antalate foxglove needs foxglove-sdk, which is not installed: pip install 'antalate[foxglove]'"
)
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765


class FoxgloveView:
    """Bus messages onto foxglove-sdk channels, one per :class:`ChannelSpec`, made on first use
    (a client sees each channel advertised as the swarm first publishes on it). Called on the bus's
    executor thread only."""

    def __init__(self, foxglove: Any, context: Any) -> None:
        self._foxglove = foxglove
        self._context = context
        self.view = JsonView(raw=False)
        self._channels: dict[ChannelSpec, Any] = {}
        self.messages = 0

    def _channel(self, spec: ChannelSpec) -> Any:
        channel = self._channels.get(spec)
        if channel is None:
            schema = self._foxglove.Schema(
                name=spec.schema_name, encoding=spec.schema_encoding, data=spec.schema_data
            )
            channel = self._channels[spec] = self._foxglove.Channel(
                spec.topic,
                schema=schema,
                message_encoding=spec.message_encoding,
                context=self._context,
                metadata=dict(spec.metadata),
            )
        return channel

    def on_message(self, channel: str, data: bytes) -> None:
        now = time.time_ns()
        for out in self.view.translate(channel, now, data):
            self._channel(out.channel).log(out.data, log_time=now)
            self.messages += 1


def serve(url: str, *, host: str, port: int, no_auth: bool, stop: threading.Event | None = None) -> int:
    """Serve the bus at ``url`` to Foxglove on ``ws://host:port`` until Ctrl-C, SIGTERM or ``stop``."""
    from operator_tui.web import is_loopback

    if not is_loopback(host) and not no_auth:
        raise AntalateError(
            f"refusing to serve the swarm's live picture on {host}: the Foxglove protocol carries no "
            "credential, so anyone who reaches the port sees every position and state. Bind --host "
            "127.0.0.1 (and tunnel to it, e.g. ssh -L 8765:127.0.0.1:8765), or pass --no-auth"
        )
    try:
        import foxglove
    except ImportError:
        raise AntalateError(FOXGLOVE_MISSING) from None
    from antalate_lcm.core.bus import Buses

    stop = stop or threading.Event()

    # The handler only raises a flag: setting an Event from a signal handler can deadlock the main
    # thread waiting on it (runtime/launch.py: run_until_signal), so the main thread polls.
    signalled: list[int] = []

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        signalled.append(signum)

    previous = (
        signal.signal(signal.SIGTERM, on_signal)
        if threading.current_thread() is threading.main_thread()
        else None
    )
    context = foxglove.Context()
    buses = Buses({"view": url})
    server = None
    try:
        buses.open()
        try:
            # No capability: no client publishing, services or parameters (read-only by construction).
            server = foxglove.start_server(
                name="antalate", host=host, port=port, capabilities=[], context=context
            )
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error type for a bind failure
            raise AntalateError(f"cannot serve Foxglove on {host}:{port}: {exc}") from None
        view = FoxgloveView(foxglove, context)
        buses.subscribe("view", ".*", None, view.on_message, regex=True)
        if not is_loopback(host):
            log.warning(
                "the Foxglove view on %s:%d has NO sign-in: anyone who reaches it sees the swarm",
                host,
                server.port,
            )
        print(f"serving {url} to Foxglove on ws://{host}:{server.port} (read-only); Ctrl-C stops", flush=True)
        try:
            while not signalled and not stop.is_set():
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
    finally:
        buses.close()
        if server is not None:
            server.stop()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0


def cmd_foxglove(args: argparse.Namespace) -> int:
    from antalate_lcm.core.config import load_config

    config = load_config(args.config)
    url = config.bus_url(config.watched_bus(args.bus))
    return serve(url, host=args.host, port=args.port, no_auth=args.no_auth)


def foxglove_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="config with the bus (default: the embedded defaults)")
    p.add_argument(
        "--bus", help="bus name from the config (default: 'lan' if declared, else the default bus)"
    )
    p.add_argument("--host", default=DEFAULT_HOST, help=f"address to listen on (default {DEFAULT_HOST})")
    p.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}; 0 = any free)"
    )
    p.add_argument(
        "--no-auth",
        action="store_true",
        help="allow a --host beyond loopback (anyone who reaches it sees the swarm)",
    )
