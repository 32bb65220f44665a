"""Three sites joined only by routed unicast: each site a LAN (a bridge in its own namespace) of hosts,
the sites' uplinks meeting in a ``core`` namespace that forwards IPv4 and nothing else.

    with Wan({"a": ["op"], "b": ["uavs", "gw"], "c": ["router"]}) as wan:
        wan["b", "uavs"].antalate("agent", ...)
        wan.set_loss("b", 20)     # 20 % of the packets through site B's uplink, each way
        wan.cut("c")              # site C unreachable (every packet through its uplink dropped)

Layout (docs/wan.md)::

    core:   sa 10.81.1.1/24   sb 10.81.2.1/24   sc 10.81.3.1/24     (ip_forward=1, no multicast routing)
              │                 │                 │
    sw-a:   br0 ── hosts of A   br0 ── hosts of B   br0 ── hosts of C
    hosts:  lan0 10.81.N.11, .12, ...; default via 10.81.N.1; 224.0.0.0/4 dev lan0 (the site's bus);
            239.255.76.68/32 dev lo (an agent's own bus)

Multicast never crosses the core (ttl=1, and the kernel routes no multicast without a daemon), so
the only way between sites is TCP to the router at site C. Loss and cuts are nftables rules in the
core's ``forward`` hook on a site's uplink. Names follow :mod:`tests.lan.topology`
(``antalate-lan-<pid>-<random>-...``), so its :func:`sweep_stale` removes what a killed run left.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import secrets
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

from tests.lan.topology import PREFIX, REPO, LanError, _run, delete_namespace, stop_process, sweep_stale

SUBNET = "10.81"
_TABLE = "antalate_wan"


class SiteHost:
    """One machine at a site: a namespace with ``lan0`` on the site's switch."""

    def __init__(self, wan: Wan, site: str, site_index: int, name: str, index: int) -> None:
        self.site = site
        self.name = name
        self.ns = f"{wan.prefix}-{site}{index}"
        self.port = f"p{index}"
        self.address = f"{SUBNET}.{site_index}.{10 + index}"
        self.gateway = f"{SUBNET}.{site_index}.1"
        self.switch = f"{wan.prefix}-sw{site}"
        self.procs: list[subprocess.Popen[str]] = []
        self._files: list[IO[str]] = []

    def build(self) -> None:
        ns = self.ns
        _run(["ip", "netns", "add", ns])
        _run(["ip", "-n", ns, "link", "set", "lo", "up"])
        _run(
            [
                "ip",
                "-n",
                self.switch,
                "link",
                "add",
                self.port,
                "type",
                "veth",
                "peer",
                "name",
                "lan0",
                "netns",
                ns,
            ]
        )
        _run(["ip", "-n", self.switch, "link", "set", self.port, "master", "br0"])
        _run(["ip", "-n", self.switch, "link", "set", self.port, "up"])
        _run(["ip", "-n", ns, "addr", "add", f"{self.address}/24", "dev", "lan0"])
        _run(["ip", "-n", ns, "link", "set", "lan0", "up"])
        _run(["ip", "-n", ns, "route", "replace", "default", "via", self.gateway])
        _run(["ip", "-n", ns, "route", "replace", "224.0.0.0/4", "dev", "lan0"])
        _run(["ip", "-n", ns, "route", "replace", "239.255.76.68/32", "dev", "lo"])

    def wrap(self, argv: Sequence[str]) -> list[str]:
        return ["ip", "netns", "exec", self.ns, *argv]

    def popen(self, argv: Sequence[str], *, log: Path | None = None, **kwargs: Any) -> subprocess.Popen[str]:
        env = dict(os.environ)
        env.setdefault("PYTHONUNBUFFERED", "1")
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
        kwargs.setdefault("env", env)
        kwargs.setdefault("text", True)
        kwargs.setdefault("start_new_session", True)
        kwargs.setdefault("cwd", str(REPO))
        if log is not None:
            out = open(log, "w")  # noqa: SIM115 - closed at teardown
            self._files.append(out)
            kwargs.setdefault("stdout", out)
            kwargs.setdefault("stderr", subprocess.STDOUT)
        proc: subprocess.Popen[str] = subprocess.Popen(self.wrap(argv), **kwargs)
        self.procs.append(proc)
        return proc

    def antalate(self, *args: str, log: Path | None = None, **kwargs: Any) -> subprocess.Popen[str]:
        return self.popen([sys.executable, "-m", "antalate_lcm.cli", *args], log=log, **kwargs)

    def stop(self) -> None:
        for proc in reversed(self.procs):
            stop_process(proc)
        self.procs.clear()
        for f in self._files:
            f.close()
        self._files.clear()


class Wan:
    """Sites of hosts behind one core router. A context manager: nothing is left after ``with``."""

    def __init__(self, sites: Mapping[str, Sequence[str]]) -> None:
        self.prefix = f"{PREFIX}-{os.getpid()}-{secrets.token_hex(3)}"
        self.core = f"{self.prefix}-core"
        self.sites = list(sites)
        self.site_index = {s: i + 1 for i, s in enumerate(self.sites)}
        self.hosts: dict[tuple[str, str], SiteHost] = {}
        for site, names in sites.items():
            for k, name in enumerate(names):
                self.hosts[(site, name)] = SiteHost(self, site, self.site_index[site], name, k + 1)
        self._loss: dict[str, int] = {}
        self._built: list[str] = []
        self._closed = False

    def __getitem__(self, key: tuple[str, str]) -> SiteHost:
        return self.hosts[key]

    def __enter__(self) -> Wan:
        sweep_stale()
        atexit.register(self.close)
        try:
            self._build()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _build(self) -> None:
        core = self.core
        _run(["ip", "netns", "add", core])
        self._built.append(core)
        _run(["ip", "-n", core, "link", "set", "lo", "up"])
        _run(["ip", "netns", "exec", core, "sysctl", "-qw", "net.ipv4.ip_forward=1"])
        for site in self.sites:
            i = self.site_index[site]
            sw = f"{self.prefix}-sw{site}"
            _run(["ip", "netns", "add", sw])
            self._built.append(sw)
            _run(["ip", "-n", sw, "link", "set", "lo", "up"])
            _run(["ip", "-n", sw, "link", "add", "br0", "type", "bridge", "mcast_snooping", "0"])
            _run(["ip", "-n", sw, "link", "set", "br0", "up"])
            _run(
                [
                    "ip",
                    "-n",
                    core,
                    "link",
                    "add",
                    f"s{site}",
                    "type",
                    "veth",
                    "peer",
                    "name",
                    "uplink",
                    "netns",
                    sw,
                ]
            )
            _run(["ip", "-n", sw, "link", "set", "dev", "uplink", "master", "br0"])
            _run(["ip", "-n", sw, "link", "set", "dev", "uplink", "up"])
            _run(["ip", "-n", core, "addr", "add", f"{SUBNET}.{i}.1/24", "dev", f"s{site}"])
            _run(["ip", "-n", core, "link", "set", f"s{site}", "up"])
        for host in self.hosts.values():
            self._built.append(host.ns)
            host.build()
        self._nft(
            f"add table inet {_TABLE}\n"
            f"add chain inet {_TABLE} forward {{ type filter hook forward priority 0; policy accept; }}\n"
        )

    def _nft(self, script: str) -> None:
        proc = subprocess.run(
            ["ip", "netns", "exec", self.core, "nft", "-f", "-"],
            input=script,
            capture_output=True,
            text=True,
            timeout=20,
        )
        if proc.returncode != 0:
            raise LanError(f"nft in {self.core} failed: {proc.stderr.strip()}")

    def set_loss(self, site: str, percent: int) -> None:
        """Drop ``percent`` % of the packets through ``site``'s uplink, both ways (0 removes it)."""
        if site not in self.site_index:
            raise KeyError(site)
        if not 0 <= percent <= 100:
            raise ValueError("loss is a percentage, 0..100")
        self._loss[site] = percent
        script = f"flush chain inet {_TABLE} forward\n"
        for s, pct in self._loss.items():
            if not pct:
                continue
            verdict = "counter drop" if pct >= 100 else f"numgen random mod 100 < {pct} counter drop"
            for hook in ("iifname", "oifname"):
                script += f'add rule inet {_TABLE} forward {hook} "s{s}" {verdict}\n'
        self._nft(script)

    def cut(self, site: str) -> None:
        self.set_loss(site, 100)

    def restore(self, site: str) -> None:
        self.set_loss(site, 0)

    def dropped(self) -> int:
        import re

        out = _run(
            ["ip", "netns", "exec", self.core, "nft", "list", "chain", "inet", _TABLE, "forward"]
        ).stdout
        return sum(int(n) for n in re.findall(r"counter packets (\d+)", out))

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for host in self.hosts.values():
            with contextlib.suppress(Exception):
                host.stop()
        for ns in reversed(self._built):
            delete_namespace(ns)
        self._built.clear()
        atexit.unregister(self.close)

    def namespaces(self) -> list[str]:
        out = _run(["ip", "netns", "list"], check=False).stdout
        return [line.split()[0] for line in out.splitlines() if line.startswith(self.prefix + "-")]
