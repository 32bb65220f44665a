"""The container's health check: is the node doing its job, judged by what it sends.

A process that is alive can still be deaf or stuck; the nodes publish their state several times a
second, so "healthy" is: the node's own message was heard on its bus within a few seconds (MC:
MC_STATE, HLC: HLC_STATE, BMA: its ARBITER status; OSC: the MC_STATE it forwards; an agent: MC_STATE
of one of its agents), or the station / web console answers HTTP on loopback. The command line of
the container's main process (``/proc/1/cmdline``: ``antalate mc CONFIG`` ...) says which node it is
and where its config is, so one image needs no per-kind check.

Exit 0 healthy, 1 unhealthy (one line saying why), as podman's HEALTHCHECK expects.
``--cmdline 'antalate mc agent.toml'`` checks a given command line instead of PID 1 (tests).
"""

from __future__ import annotations

import argparse
import re
import shlex
import ssl
import sys
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path

LISTEN_S = 5.0
KINDS = ("mc", "hlc", "bma", "osc", "agent", "station", "tui")


@dataclass(frozen=True)
class LcmCheck:
    urls: tuple[str, ...]
    channel_regex: str
    what: str


@dataclass(frozen=True)
class HttpCheck:
    url: str
    what: str


@dataclass(frozen=True)
class NothingToCheck:
    why: str


Check = LcmCheck | HttpCheck | NothingToCheck


def node_args(cmdline: list[str]) -> list[str]:
    """The arguments after ``antalate`` (or ``python -m antalate_lcm.cli``) in a command line."""
    for i, arg in enumerate(cmdline):
        if Path(arg).name == "antalate" or arg == "antalate_lcm.cli":
            return cmdline[i + 1 :]
    return []


def plan(cmdline: list[str]) -> Check:
    """What to check for this command line (pure apart from reading the node's config file)."""
    from antalate_lcm.cli import build_parser
    from antalate_lcm.core.config import load_config

    rest = node_args(cmdline)
    args = build_parser().parse_args(rest)
    kind = args.command
    if kind == "station":
        return HttpCheck(_station_url(args), "the station")
    if kind == "tui":
        if not getattr(args, "web", False):
            return NothingToCheck("a terminal console")
        return HttpCheck(f"http://127.0.0.1:{args.port}/login", "the web console")
    if kind not in ("mc", "hlc", "bma", "osc", "agent"):
        return NothingToCheck(f"antalate {kind}")
    config = load_config(args.config[0] if kind == "agent" else args.config)
    name = re.escape(config.agent.name) + (r"(-\d+)?" if kind == "agent" else "")
    topic = {"hlc": "HLC_STATE", "bma": "ARBITER"}.get(kind, "MC_STATE")
    template = config.topic_specs()[topic].channel
    regex = re.escape(template).replace(re.escape("{agent}"), name)
    regex = regex.replace(re.escape("{arbiter}"), re.escape(getattr(args, "name", "") or ""))
    urls = tuple(config.buses[b] for b in config.topic_buses(topic) if config.buses[b].startswith("udpm://"))
    if not urls:
        return NothingToCheck(f"{topic} travels only in memory")
    what = {
        "mc": "MC_STATE",
        "hlc": "HLC_STATE",
        "bma": "the arbiter's status",
        "osc": "the MC_STATE it forwards",
        "agent": "an agent's MC_STATE",
    }[kind]
    return LcmCheck(urls, regex, what)


def _station_url(args: argparse.Namespace) -> str:
    from antalate_lcm.station import DEFAULT_PORT, load_station_file

    host, port, tls = "127.0.0.1", DEFAULT_PORT, bool(args.tls_cert)
    if args.config:
        f = load_station_file(args.config)
        host, port, tls = f.host or host, f.port or DEFAULT_PORT, tls or bool(f.tls_cert)
    host = args.host or host
    if host in ("0.0.0.0", "::", ""):  # every address: loopback is one of them
        host = "127.0.0.1"
    if args.port is not None:
        port = args.port
    shown = f"[{host}]" if ":" in host else host
    return f"{'https' if tls else 'http'}://{shown}:{port}/api/station"


def run_check(check: Check, listen_s: float = LISTEN_S) -> str | None:
    """None if healthy, else why not."""
    if isinstance(check, NothingToCheck):
        return None
    if isinstance(check, HttpCheck):
        context = (
            ssl._create_unverified_context() if check.url.startswith("https") else None
        )  # loopback, own cert
        try:
            with urllib.request.urlopen(check.url, timeout=listen_s, context=context) as reply:
                return None if reply.status < 500 else f"{check.what} answered {reply.status}"
        except urllib.error.HTTPError as exc:
            return None if exc.code < 500 else f"{check.what} answered {exc.code}"
        except OSError as exc:
            return f"{check.what} does not answer on {check.url}: {exc}"
    import lcm

    heard: list[str] = []
    instances = []
    for url in check.urls:
        lc = lcm.LCM(url)
        lc.subscribe(check.channel_regex, lambda channel, data: heard.append(channel))
        instances.append(lc)
    deadline = time.monotonic() + listen_s
    while not heard and time.monotonic() < deadline:
        for lc in instances:
            lc.handle_timeout(50)
    if heard:
        return None
    return f"{check.what} not heard ({check.channel_regex}) on {', '.join(check.urls)} in {listen_s:g} s"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="health of the antalate node in this container")
    parser.add_argument("--cmdline", help="check this command line instead of PID 1's")
    parser.add_argument("--listen", type=float, default=LISTEN_S, help="seconds to listen (default 5)")
    opts = parser.parse_args(argv)
    if opts.cmdline:
        cmdline = shlex.split(opts.cmdline)
    else:
        cmdline = [a.decode() for a in Path("/proc/1/cmdline").read_bytes().split(b"\0") if a]
    try:
        check = plan(cmdline)
    except SystemExit:
        print(f"unhealthy: not an antalate command line: {' '.join(cmdline)}")
        return 1
    except Exception as exc:  # a config that no longer loads is unhealthy, with the reason
        print(f"unhealthy: {exc}")
        return 1
    problem = run_check(check, opts.listen)
    if problem:
        print(f"unhealthy: {problem}")
        return 1
    print("healthy" + (f" ({check.why})" if isinstance(check, NothingToCheck) else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
