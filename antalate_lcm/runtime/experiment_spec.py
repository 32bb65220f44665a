"""What ``antalate run`` is asked to fly (:class:`Experiment`) and everything checked before anything
flies (:func:`prepare`): the config and its plugins (as ``antalate agent``), the script (one line
naming the key), the recorded bus, and that this process can hear and command agents that run in
other processes (buses their transport carries across processes). ``antalate sweep`` runs the same
checks on every point of a sweep before its first run. The argument types of ``--speed`` and
``--stall-timeout`` are here too: they are values of an :class:`Experiment`.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

from antalate_lcm.base.errors import AntalateError, ConfigError
from antalate_lcm.core.config import Config, check_unique_agent_names, load_config
from antalate_lcm.runtime.agent import swarm_configs, validate
from antalate_lcm.runtime.cli import positive_number
from antalate_lcm.runtime.script import Script, check_fault_agents
from antalate_lcm.runtime.time_coordinator import DEFAULT_STALL
from antalate_lcm.transports import transport_for

#: Topics this process must hear or send when the agents are in other processes.
_OPERATOR_TOPICS = ("MC_STATE", "TELEMETRY", "SWARM_OPERATOR_CMD", "SWARM_DIRECTION_CMD")


@dataclass(frozen=True)
class Experiment:
    config_path: str
    agents: int = 1
    processes: int = 1
    spacing: float = 8.0
    script: Script | None = None
    output: str | None = None
    bus: str | None = None
    headless: bool = True
    force: bool = False
    log_level: str = "INFO"
    #: Where the script came from, for the errors that name its keys.
    script_source: str = "script"
    #: Simulated time (``--speed``): simulated seconds per real second at most, ``math.inf`` as
    #: fast as this process computes; None: the wall clock.
    speed: float | None = None
    #: ``--seed``: the script's seed (every draw); with ``speed`` the run is a pure function of it.
    seed: int | None = None
    #: False: no metrics at the end (benchmarks/simtime.py times the flight, not the analysis).
    measure: bool = True
    #: ``--stall-timeout``: real seconds an agent process on the shared clock may go silent
    #: before it is taken as hung (``--speed`` with ``--processes``).
    stall_timeout: float = DEFAULT_STALL


def default_log_path() -> str:
    return time.strftime("antalate-run-%Y%m%d-%H%M%S.lcm")


def record_bus(config: Config, bus: str | None) -> str:
    """The bus to record (`Config.watched_bus`, as ``antalate log``); it must carry the telemetry and
    the MC states, or the log would hold nothing to analyse."""
    name = config.watched_bus(bus)
    config.bus_url(name)  # refuses an undeclared name
    for topic in ("TELEMETRY", "MC_STATE"):
        if name not in config.topic_buses(topic):
            raise ConfigError(
                config.source,
                f"topics.{topic}",
                f"a binding that includes the recorded bus {name!r} (or pass --bus one of "
                f"{', '.join(config.topic_buses(topic))})",
            )
    return name


def check_reach(config: Config, processes: int, recorded: str) -> None:
    """With agents in other processes, every bus this process uses to hear or command them must
    cross processes: a ``memq://`` bus would fly agents nobody commands and record nothing."""
    if processes <= 1:
        return
    for topic in _OPERATOR_TOPICS:
        for name in config.topic_buses(topic):
            url = config.buses.get(name)
            if url is not None and not transport_for(url).crosses_processes:
                raise ConfigError(
                    config.source,
                    f"buses.{name}",
                    f"a bus other processes reach (udpm:// or zenoh://) with --processes {processes}: "
                    f"{topic} travels on it and {url!r} stays inside one process",
                )
    if not transport_for(config.buses[recorded]).crosses_processes:
        raise ConfigError(
            config.source,
            f"buses.{recorded}",
            f"a bus other processes reach to record with --processes {processes}",
        )


def prepare(exp: Experiment) -> tuple[list[Config], str, str]:
    """The agents' configs, the recorded bus and the log path: every check before anything flies."""
    if exp.agents < 1:
        raise AntalateError(f"--agents wants a number >= 1 (got {exp.agents})")
    if exp.processes < 1:
        raise AntalateError(f"--processes wants a number >= 1 (got {exp.processes})")
    if exp.speed is not None:
        check_simulated(exp)
    if exp.seed is not None and exp.seed < 0:
        raise AntalateError(f"--seed wants a number >= 0 (got {exp.seed})")
    base = load_config(exp.config_path)
    configs = swarm_configs(base, exp.agents, spacing=exp.spacing)
    check_unique_agent_names(configs, agents=exp.agents)
    for cfg in configs:
        validate(cfg)
    if exp.speed is not None and base.hlc.autopilot != "sim":
        raise ConfigError(
            base.source,
            "hlc.autopilot",
            f"'sim' with --speed: a {base.hlc.autopilot!r} vehicle flies in real time, not on a simulated clock",
        )
    if exp.speed is not None and base.osc.enabled:
        raise ConfigError(
            base.source,
            "osc.enabled",
            "false with --speed: the OSC's station answers over HTTP in real time, not on a simulated clock",
        )
    bus = record_bus(base, exp.bus)
    check_reach(base, min(exp.processes, len(configs)), bus)
    if exp.script is not None:
        check_interference(exp, exp.script, configs)
    out = exp.output or default_log_path()
    if os.path.exists(out) and not exp.force:
        raise AntalateError(f"{out} exists: pass --force to overwrite it, or -o another file")
    parent = Path(out).resolve().parent
    if not parent.is_dir():
        raise AntalateError(f"cannot write the log {out}: {parent} is not a folder")
    return configs, bus, out


def check_simulated(exp: Experiment) -> None:
    """Simulated time needs a number, and the scripted operator (the console runs on the wall clock)."""
    if not exp.speed or exp.speed <= 0 or math.isnan(exp.speed):
        raise AntalateError(f"--speed wants 'max' or a number > 0 (got {exp.speed})")
    if not exp.headless:
        raise AntalateError("--speed needs --headless: the operator console runs on the wall clock")


def check_interference(exp: Experiment, script: Script, configs: list[Config]) -> None:
    """Faults and lossy broadcasts act on simulated agents in this process, under the scripted
    operator (their times count from its MISSION); each fault names agents that fly."""
    if not script.interferes:
        return
    if script.fault and not exp.headless:
        raise AntalateError(
            f"{exp.script_source}: [[fault]] needs --headless (its times count from the scripted MISSION)"
        )
    for i, f in enumerate(script.fault):
        if f.kind in ("battery", "vehicle") and configs[0].hlc.autopilot != "sim":
            raise ConfigError(
                exp.script_source,
                f"fault[{i}].kind",
                f"a {f.kind} fault on a simulated vehicle (hlc.autopilot = 'sim')",
            )
    check_fault_agents(script, [c.agent.name for c in configs], exp.script_source)
    if script.broadcast.reception < 1.0 and configs[0].hlc.autopilot != "sim":
        raise ConfigError(
            exp.script_source, "broadcast.reception", "simulated agents (hlc.autopilot = 'sim')"
        )


_SPEED_NUMBER = positive_number("'max' or a number > 0", "'max' or a number > 0")


def parse_speed(text: str) -> float:
    """``--speed``: ``max`` (math.inf) or a number > 0."""
    return math.inf if text == "max" else _SPEED_NUMBER(text)


#: ``--stall-timeout``: a number of seconds > 0 (not NaN, not infinite: a hang must end).
parse_stall = positive_number("a number of seconds > 0", "a number of seconds > 0")


__all__ = [
    "Experiment",
    "check_interference",
    "check_reach",
    "check_simulated",
    "default_log_path",
    "parse_speed",
    "parse_stall",
    "prepare",
    "record_bus",
]
