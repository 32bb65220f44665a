"""``antalate demo`` with the operator console: station, simulated swarm and console in one process.

The agents and the station run on background threads; the console owns the terminal. Their logs go
to a file (the console shows warnings and errors in its event log), whose path is printed on exit.
Quitting the console stops everything the demo started: it starts no other process.
"""

from __future__ import annotations

import contextlib
import logging
import os
import tempfile
from collections.abc import Iterator

from antalate_lcm.core.node import Node
from antalate_lcm.runtime.agent import agent_nodes
from antalate_lcm.runtime.demo import DEMO_URL, build_swarm, open_context, start_station
from antalate_lcm.station import new_api_key
from antalate_lcm.wire.security import generate_key


@contextlib.contextmanager
def _log_to_file(path: str) -> Iterator[None]:
    root = logging.getLogger()
    saved = list(root.handlers)
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s"))
    for h in saved:
        root.removeHandler(h)
    root.addHandler(handler)
    try:
        yield
    finally:
        root.removeHandler(handler)
        handler.close()
        for h in saved:
            root.addHandler(h)


def run_interactive(n: int, *, url: str = DEMO_URL) -> int:
    from operator_tui.app import OperatorApp

    fd, log_path = tempfile.mkstemp(prefix="antalate-demo-", suffix=".log")
    os.close(fd)
    nodes: list[Node] = []
    swarm_key, api_key = generate_key(), new_api_key()
    key_path = log_path.removesuffix(".log") + ".api-key"
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(api_key + "\n")
    with _log_to_file(log_path):
        station = start_station(swarm_key, api_key)
        logging.getLogger("antalate.demo").info(
            "station on %s; its API key (role operator) is in %s: antalate command agents --station %s "
            "--api-key-file %s",
            station.url,
            key_path,
            station.url,
            key_path,
        )
        context, url = open_context(url)
        try:
            configs = build_swarm(n, url, station=station.url, swarm_key=swarm_key)
            context.executor.start()
            for cfg in configs:
                for node in agent_nodes(cfg, context):
                    node.start()
                    nodes.append(node)
            app = OperatorApp(configs[0], context=context, name="operator")
            app.run()
            code = app.return_code or 0
        finally:
            for node in reversed(nodes):
                with contextlib.suppress(Exception):
                    node.stop()
            context.close()
            station.stop()
    with contextlib.suppress(OSError):
        os.unlink(key_path)  # the station it opened is gone
    print(f"antalate demo: {n} agents flown; the log is in {log_path}")
    return code
