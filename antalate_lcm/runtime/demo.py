"""``antalate demo``: a simulated swarm running the template application, in one process.

The swarm flies the paper's template application (``dovrat_swarm`` active in MISSION). With
``--headless`` a scripted operator takes off all, lets the mission run, commands RTL and prints each
agent's state timeline; the exit status is 0 only when every agent came back to STANDBY.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from antalate_lcm.base.errors import MulticastUnavailable
from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import Config, parse_config
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.runtime.agent import agent_nodes, swarm_configs, validate
from antalate_lcm.runtime.launch import run_until_signal
from antalate_lcm.runtime.scripted_operator import Phase, ScriptedOperator
from antalate_lcm.station import StationServer, StationSettings
from antalate_lcm.wire.security import generate_key

log = logging.getLogger("antalate.demo")

#: The demo runs in one process, but on real multicast when it can, so lcm-spy and
#: `antalate tui` in another terminal see it too; ttl=0 keeps it on this host.
DEMO_URL = "udpm://239.255.76.67:7667?ttl=0"


def demo_document(url: str, *, station: str | None = None, swarm_key: str = "") -> dict[str, Any]:
    """The config of one demo agent (as a TOML-like dict): the template swarm application.

    The demo's operator is in the same process, so it signs with a key made for this run: ttl=0
    limits what the demo sends, not what it receives (docs/security.md), and an unsigned demo would
    take off for any datagram from the LAN. Other processes can watch it, not command it.
    """
    doc: dict[str, Any] = {
        "agent": {"name": "sim"},
        "buses": {"lan": url},
        "security": {"swarm_key": swarm_key or generate_key()},
        "hlc": {"autopilot": "sim", "default_takeoff_altitude": 10.0},
        "bma": [
            {
                "name": "swarm",
                "behaviors": [
                    {
                        "plugin": "dovrat_swarm",
                        "activate_on": ["MISSION"],
                        "params": {"forward_speed": 2.0},
                    }
                ],
            }
        ],
    }
    if station:
        doc["osc"] = {"enabled": True, "server": station, "rate": 2.0}
    return doc


def open_context(url: str) -> tuple[Context, str]:
    """A context on ``url``, or on ``memq://`` when this host has no multicast route (said once)."""
    probe = Buses({"lan": url})
    try:
        probe.open()
    except MulticastUnavailable as exc:
        log.warning("%s\nThe demo carries on in one process on memq:// (invisible to other processes).", exc)
        url = "memq://"
    finally:
        probe.close()
    return Context.in_process({"lan": url}, whole_swarm=True), url  # every agent of the demo is here


def build_swarm(n: int, url: str, *, station: str | None = None, swarm_key: str = "") -> list[Config]:
    base = parse_config(demo_document(url, station=station, swarm_key=swarm_key), "<demo>")
    configs = swarm_configs(base, n)
    for cfg in configs:
        validate(cfg)
    return configs


def start_station(swarm_key: str = "", api_key: str = "") -> StationServer:
    """The reference station in this process (in-memory database): the swarm's peer sensing.

    With the demo's swarm key the agents register by proof (the station holds only the derived
    key); ``api_key`` lets the demo's operator use the station's API (``antalate command``). Every
    agent registers from 127.0.0.1 at once, so the per-address registration limit is off.
    """
    from antalate_lcm.station import ApiKey, RateLimits, registration_key, sha256_hex

    server = StationServer(
        StationSettings(
            db_path=":memory:",
            range_m=30.0,
            fov_deg=90.0,
            stale_after_s=3.0,
            registration_key=registration_key(swarm_key) if swarm_key else None,
            api_keys=(ApiKey(name="demo-operator", role="operator", sha256=sha256_hex(api_key)),)
            if api_key
            else (),
            rate_limits=RateLimits(registrations_per_minute=None),
        )
    )
    server.start()
    log.info("station serving on %s", server.url)
    return server


def run_headless(
    n: int,
    *,
    mission_time: float = 20.0,
    url: str = DEMO_URL,
    direction: tuple[float, float] | None = None,
    with_station: bool = True,
    on_report: Callable[[str], None] = print,
) -> int:
    swarm_key = generate_key()
    station = start_station(swarm_key) if with_station else None
    try:
        return _fly_headless(
            n, mission_time, url, direction, station.url if station else None, on_report, swarm_key
        )
    finally:
        if station is not None:
            station.stop()


def _fly_headless(
    n: int,
    mission_time: float,
    url: str,
    direction: tuple[float, float] | None,
    station: str | None,
    on_report: Callable[[str], None],
    swarm_key: str = "",
) -> int:
    context, url = open_context(url)
    configs = build_swarm(n, url, station=station, swarm_key=swarm_key)
    nodes: list[Node] = [node for cfg in configs for node in agent_nodes(cfg, context)]
    operator = ScriptedOperator(
        NodeSettings.from_config(configs[0], agent="operator"),
        context,
        expected_agents=n,
        mission_time=mission_time,
        direction=direction,
        timeout=mission_time + 180.0,  # take-off and the return flight get three minutes together
    )
    nodes.append(operator)
    run_until_signal(context, nodes, poll=lambda: operator.finished)
    on_report(operator.report())
    return 0 if operator.phase is Phase.DONE else 1
