"""Assemble the nodes of one agent, or of many agents, to run in one process.

An agent is an MC, an HLC, its BMAs and (optionally) an OSC. Running them in one process or each in
its own (``antalate mc|hlc|bma|osc``) changes nothing for behaviors or configs: they meet on the bus.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from types import FrameType
from typing import IO

from antalate_lcm.agent.hlc.node import HlcNode
from antalate_lcm.agent.mc.node import McNode
from antalate_lcm.agent.plan import AgentPlan, plan_adapter, plan_agent
from antalate_lcm.base.errors import AntalateError, ConfigError
from antalate_lcm.base.geo import offset
from antalate_lcm.core.config import AgentConfig, Config
from antalate_lcm.core.node import Context, Node
from antalate_lcm.transports import spawn_lock
from antalate_lcm.vehicles.sim import DEFAULTS as SIM_DEFAULTS

log = logging.getLogger("antalate.agent")


def validate(config: Config) -> AgentPlan:
    """Every plugin of the agent loaded and its params checked (`antalate_lcm.agent.plan`), before any node
    starts, so a typo never surfaces mid-flight."""
    return plan_agent(config)


def agent_nodes(config: Config, context: Context, plan: AgentPlan | None = None) -> list[Node]:
    """The nodes of one agent, in start order: HLC first so the MC hears its state at once.

    Built from ``plan`` (made by `validate`; made here when not given), so what was checked runs.
    """
    from antalate_lcm.agent.bma.node import BmaNode

    plan = plan if plan is not None else plan_agent(config)
    adapter = plan.adapter.build(context.executor.clock)
    nodes: list[Node] = [HlcNode(config, context, adapter), McNode(config, context)]
    nodes.extend(BmaNode(config, context, bma.config, bma) for bma in plan.bmas)
    if config.osc.enabled:
        from antalate_lcm.agent.osc.node import OscNode

        nodes.append(OscNode(config, context))
    return nodes


def swarm_configs(
    config: Config, n: int, *, spacing: float = 8.0, base_name: str | None = None
) -> list[Config]:
    """``n`` copies of a simulated agent's config with distinct names and homes on a square grid.

    Homes are ``spacing`` metres apart so the vehicles never start inside each other.
    """
    if n < 1:
        raise ConfigError(config.source, "--agents", "a number of agents >= 1")
    if n == 1:
        return [config]
    if config.hlc.autopilot != "sim":
        plan_adapter(config)  # the adapter's own mistakes first: they are what to fix in the file
        raise ConfigError(
            config.source,
            "hlc.autopilot",
            f"'sim' for --agents N (each {config.hlc.autopilot!r} vehicle needs its own config: "
            "pass several config files to `antalate agent` instead)",
        )
    name = base_name or config.agent.name
    if name.startswith("anon-"):
        name = "sim"
    params = config.hlc.autopilot_params
    lat0 = float(params.get("home_lat", SIM_DEFAULTS["home_lat"]))
    lon0 = float(params.get("home_lon", SIM_DEFAULTS["home_lon"]))
    side = math.ceil(math.sqrt(n))
    out = []
    for i in range(n):
        north, east = (i // side) * spacing, (i % side) * spacing
        lat, lon = offset(lat0, lon0, north, east)
        hlc = config.hlc.model_copy(update={"autopilot_params": {**params, "home_lat": lat, "home_lon": lon}})
        out.append(
            config.model_copy(
                update={
                    "agent": AgentConfig(name=f"{name}-{i + 1:02d}" if n < 100 else f"{name}-{i + 1:03d}"),
                    "hlc": hlc,
                }
            )
        )
    return out


def shared_buses(configs: Sequence[Config]) -> dict[str, str]:
    """The union of the configs' buses; one name must mean one URL in a process."""
    buses: dict[str, str] = {}
    for cfg in configs:
        for name, url in cfg.buses.items():
            if buses.setdefault(name, url) != url:
                raise ConfigError(
                    cfg.source, f"buses.{name}", f"the same URL as in the other configs ({buses[name]!r})"
                )
    return buses


#: Agents above which ``antalate agent`` spreads them over one process per core by default
#: (one process holds about a thousand simulated agents: benchmarks/agents.py).
AUTO_PROCESSES_FROM = 500


def default_processes(n_agents: int) -> int:
    """One process per core on a big swarm, else one (a process has its own loop, so its own core)."""
    return max(1, min(os.cpu_count() or 1, n_agents)) if n_agents >= AUTO_PROCESSES_FROM else 1


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/P"`` (0-based): this process runs the i-th of P shares of the agents."""
    try:
        index, count = (int(part) for part in text.split("/"))
    except ValueError:
        raise AntalateError(f"--shard wants INDEX/COUNT, e.g. 0/2 (got {text!r})") from None
    if not 0 <= index < count:
        raise AntalateError(f"--shard wants 0 <= INDEX < COUNT (got {text!r})")
    return index, count


def shard(configs: Sequence[Config], index: int, count: int) -> list[Config]:
    """The ``index``-th of ``count`` contiguous shares: every node of an agent stays in one process,
    so its internal topics still travel in memory."""
    n = len(configs)
    return list(configs[index * n // count : (index + 1) * n // count])


def _die_with_parent() -> None:
    """In an agent process, before exec: SIGTERM when the launcher dies, even by SIGKILL (Linux
    PR_SET_PDEATHSIG), so no swarm is left running behind a killed launcher."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # not Linux: Ctrl-C still reaches the whole group
        pass


def run_processes(
    child_argv: Callable[[int, int], list[str]],
    count: int,
    *,
    grace: float = 60.0,
    stop: threading.Event | None = None,
    output: IO[bytes] | None = None,
) -> int:
    """Run ``count`` agent processes (``child_argv(i, count)`` each) until a signal or one exits.

    Ctrl-C reaches every process of the terminal's group at once; SIGTERM here (or one child
    ending) is passed on as SIGINT so each child stops its nodes in order (MC before HLC, the
    vehicle in a safe state) and closes its bus; a child still running after ``grace`` s is killed.
    A launcher killed outright takes its children along (they get SIGTERM). ``stop`` set by
    another thread (``antalate run`` once its operator is done) ends them the same way; ``output``
    takes the children's stdout and stderr (a console owns the terminal) instead of this process's.
    """
    stop = stop if stop is not None else threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("received %s, stopping %d agent processes", signal.Signals(signum).name, count)
        stop.set()

    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_signal)
    procs: list[subprocess.Popen[bytes]] = []
    try:
        for i in range(count):
            with (
                spawn_lock()
            ):  # not while another thread has fd 2 swapped out: the child's lines would go there
                procs.append(
                    subprocess.Popen(
                        child_argv(i, count), preexec_fn=_die_with_parent, stdout=output, stderr=output
                    )
                )
        log.info("%d agent processes: %s", count, ", ".join(str(p.pid) for p in procs))
        failed: subprocess.Popen[bytes] | None = None
        while not stop.is_set():  # never stop.wait(): see launch.run_until_signal
            time.sleep(0.2)
            if stop.is_set():  # a Ctrl-C reaches the children too: their exit is not a failure then
                break
            failed = next((p for p in procs if p.poll() is not None), None)
            if failed is not None:
                log.error(
                    "agent process %d exited with %s; stopping the others", failed.pid, failed.returncode
                )
                break
        return (failed.returncode or 1) if failed is not None else 0
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        deadline = time.monotonic() + grace
        for p in procs:
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.error("agent process %d did not stop within %.0f s; killed", p.pid, grace)
                p.kill()
                p.wait()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
