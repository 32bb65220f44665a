"""A simulated LAN: K hosts (network namespaces) plugged into one switch (a bridge in its own namespace).

    with Lan(["uav-1", "uav-2", "operator"]) as lan:
        proc = lan["uav-1"].popen(["antalate", "agent", "uav-1.toml"], log=path)
        lan.set_loss(20)          # drop 20 % of the frames the switch forwards
        lan.cut("uav-2")          # take uav-2's network interface down (cable pulled)
        lan.restore("uav-2")

Layout (docs/design.md §12, §13)::

    namespace <prefix>-sw:  br0 ── p1 ─┐ ── p2 ─┐ ...            (the switch; multicast snooping off)
                                       │        │
    namespace <prefix>-h1:  lan0 10.77.0.11/24  │               (a host: lo up, multicast routes)
    namespace <prefix>-h2:           lan0 10.77.0.12/24

Every interface is created directly inside its namespace (``ip -n``), so nothing ever appears on the
host's own network, and 10.77.0.0/24 exists only behind the private bridge. Each host gets:

* ``224.0.0.0/4 dev lan0``: the LAN bus (``ttl=1``) goes to the switch;
* ``239.255.76.68/32 dev lo`` (:data:`LOCAL_GROUP`): an agent's own bus stays on ``lo``. Without
  it the local bus would also be routed to ``lan0``, and taking ``lan0`` down deletes that route:
  every send on the local bus would fail with ENETUNREACH and the agent's nodes would lose each other
  exactly when the LAN is gone (measured; see docs/lan.md).

Packet loss is an nftables rule on the switch's bridge ``forward`` hook
(``numgen random mod 100 < N drop``): ``tc netem`` is missing on some kernels, and dropping at a
sender's own output makes its ``publish`` raise EPERM instead of losing the datagram silently.

Names are ``antalate-lan-<pid>-<random>-<role>``: parallel runs never collide, and
:func:`sweep_stale` removes the namespaces of runs whose process is gone (a crash, a SIGKILL),
only those of this harness. Teardown (also on an exception) kills every process started in the
hosts, then any process left in the namespaces, then deletes the namespaces.

:class:`Wan` builds sites of such LANs from the same :class:`Host` and teardown: three sites
joined only by routed unicast, each a LAN (a bridge in its own namespace) of hosts, their uplinks
meeting in a ``core`` namespace that forwards IPv4 and nothing else.

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
core's ``forward`` hook on a site's uplink. Names are the LAN's, so
:func:`sweep_stale` removes what a killed run left.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import re
import secrets
import shutil
import subprocess
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

from tests.harness.lifecycle import Started
from tests.harness.netns import NetNamespace, delete_named

PREFIX = "antalate-lan"
SUBNET = "10.77.0"
#: The WAN's sites are 10.81.<site>.0/24, their router 10.81.<site>.1.
WAN_SUBNET = "10.81"
#: The multicast group of the agents' own (``local``) bus in the LAN example configs.
LOCAL_GROUP = "239.255.76.68"
_NAME = re.compile(rf"^{PREFIX}-(\d+)-([0-9a-f]+)-")
_LOSS_TABLE = "antalate_loss"


class LanError(RuntimeError):
    """A set-up command failed; the message holds the command and what it printed."""


def _run(argv: Sequence[str], *, check: bool = True, timeout: float = 20) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(list(argv), capture_output=True, text=True, timeout=timeout)
    if check and proc.returncode != 0:
        raise LanError(
            f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr.strip() or proc.stdout.strip()}"
        )
    return proc


def lan_unavailable() -> str | None:
    """Why a simulated LAN cannot be built here (None when it can): the reason a test skips with."""
    if sys.platform != "linux":
        return "network namespaces need Linux"
    if os.geteuid() != 0:
        return "needs root (ip netns add, veth, bridges, nftables)"
    for tool, pkg in (("ip", "iproute2"), ("nft", "nftables")):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (apt-get install {pkg}; tools/install-system-deps.sh does it)"
    try:
        with Lan(1):
            pass
    except (LanError, OSError, subprocess.SubprocessError) as exc:
        return f"cannot build a test LAN: {exc}"
    return None


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _namespaces() -> list[str]:
    out = _run(["ip", "netns", "list"], check=False).stdout
    return [line.split()[0] for line in out.splitlines() if line.strip()]


def sweep_stale() -> list[str]:
    """Delete the namespaces left by runs of this harness whose process no longer exists."""
    removed = []
    for ns in _namespaces():
        m = _NAME.match(ns)
        if m and int(m.group(1)) != os.getpid() and not _pid_alive(int(m.group(1))):
            delete_named(ns)
            removed.append(ns)
    return removed


class Host:
    """One simulated machine: a named network namespace (tests/harness/netns.py) with one interface
    (``lan0``) on a switch. What runs in it is the namespace's; the cable and routes are the host's."""

    def __init__(
        self, name: str, ns: str, switch: str, port: str, address: str, gateway: str | None = None
    ) -> None:
        self.name = name
        self.ns = ns
        self.netns = NetNamespace(name=ns)
        #: The switch's namespace, and the switch-side end of this host's cable in it.
        self.switch = switch
        self.port = port
        self.address = address
        #: The site's router (a WAN host); a LAN host has no route beyond its switch.
        self.gateway = gateway

    def __repr__(self) -> str:
        return f"Host({self.name!r}, {self.ns}, {self.address})"

    @property
    def procs(self) -> list[subprocess.Popen[str]]:
        """The processes started in this host and not stopped yet."""
        return self.netns.procs

    # ------------------------------------------------------------------ set-up
    def build(self) -> None:
        ns, sw = self.ns, self.switch
        self.netns.start()
        _run(["ip", "-n", sw, "link", "add", self.port, "type", "veth", "peer", "name", "lan0", "netns", ns])
        _run(["ip", "-n", sw, "link", "set", self.port, "master", "br0"])
        _run(["ip", "-n", sw, "link", "set", self.port, "up"])
        _run(["ip", "-n", ns, "addr", "add", f"{self.address}/24", "dev", "lan0"])
        _run(["ip", "-n", ns, "link", "set", "lan0", "up"])
        self._routes()

    def _routes(self) -> None:
        if self.gateway is not None:
            _run(["ip", "-n", self.ns, "route", "replace", "default", "via", self.gateway])
        _run(["ip", "-n", self.ns, "route", "replace", "224.0.0.0/4", "dev", "lan0"])
        _run(["ip", "-n", self.ns, "route", "replace", f"{LOCAL_GROUP}/32", "dev", "lo"])

    def link_down(self) -> None:
        """The host's own interface down: like pulling its cable and the OS noticing.

        This is the harsh case: the kernel deletes every route through ``lan0`` (the multicast one
        too), so sends to the LAN fail at once with ENETUNREACH.
        """
        _run(["ip", "-n", self.ns, "link", "set", "lan0", "down"])

    def link_up(self) -> None:
        _run(["ip", "-n", self.ns, "link", "set", "lan0", "up"])
        self._routes()  # the kernel dropped them with the link

    def routes(self) -> str:
        return _run(["ip", "-n", self.ns, "route", "show"]).stdout

    # ------------------------------------------------------------------ processes
    def wrap(self, argv: Sequence[str]) -> list[str]:
        return self.netns.wrap(argv)

    def popen(self, argv: Sequence[str], *, log: Path | None = None, **kwargs: Any) -> subprocess.Popen[str]:
        """Start ``argv`` in this host (its own process group, so teardown can kill its children)."""
        return self.netns.popen(argv, log=log, **kwargs)

    def antalate(self, *args: str, log: Path | None = None, **kwargs: Any) -> subprocess.Popen[str]:
        return self.netns.antalate(*args, log=log, **kwargs)

    def run(
        self, argv: Sequence[str], timeout: float = 30, check: bool = False
    ) -> subprocess.CompletedProcess[str]:
        done = self.netns.run(argv, timeout)
        if check and done.returncode != 0:
            raise LanError(
                f"{' '.join(self.wrap(argv))} failed ({done.returncode}): "
                f"{done.stderr.strip() or done.stdout.strip()}"
            )
        return done

    def stop(self, timeout: float = 5.0) -> dict[int, int | None]:
        """SIGTERM every process started here (then SIGKILL the stubborn), newest first."""
        return self.netns.stop(timeout)


class _Topology(Started):
    """What a LAN and a WAN share: build inside ``with``, a loss table, and a teardown that leaves
    nothing (hosts' processes, then the namespaces in reverse order of creation)."""

    #: The nftables family and table of the loss rules, and the namespace they live in (set by _build).
    _FAMILY = ""
    _TABLE = ""

    def __init__(self) -> None:
        self.prefix = f"{PREFIX}-{os.getpid()}-{secrets.token_hex(3)}"
        self._filter_ns = ""
        self._built: list[str] = []
        self._closed = False

    def _all_hosts(self) -> Iterable[Host]:
        raise NotImplementedError

    def _build(self) -> None:
        raise NotImplementedError

    def _start(self) -> None:
        self._build()

    def __enter__(self: _T) -> _T:
        sweep_stale()
        atexit.register(self.close)
        return super().__enter__()

    def _namespace(self, ns: str) -> str:
        self._built.append(ns)
        NetNamespace(name=ns, multicast=False).start()
        return ns

    def _switch(self, ns: str) -> str:
        """A switch: a bridge in its own namespace. Snooping off: a bridge that snoops forwards a group
        only to ports it saw an IGMP report on (and floods only while no querier exists), so delivery
        would hinge on report timing and membership timeouts. A small flat LAN switch floods
        multicast; so does this one."""
        self._namespace(ns)
        _run(["ip", "-n", ns, "link", "add", "br0", "type", "bridge", "mcast_snooping", "0"])
        _run(["ip", "-n", ns, "link", "set", "br0", "up"])
        return ns

    def _add_hosts(self) -> None:
        for host in self._all_hosts():
            self._built.append(host.ns)
            host.build()

    def _loss_table(self, ns: str) -> None:
        self._filter_ns = ns
        self._nft(
            f"add table {self._FAMILY} {self._TABLE}\n"
            f"add chain {self._FAMILY} {self._TABLE} forward "
            "{ type filter hook forward priority 0; policy accept; }\n"
        )

    def _nft(self, script: str) -> str:
        proc = subprocess.run(
            ["ip", "netns", "exec", self._filter_ns, "nft", "-f", "-"],
            input=script,
            capture_output=True,
            text=True,
            timeout=20,
        )
        if proc.returncode != 0:
            raise LanError(f"nft in {self._filter_ns} failed: {proc.stderr.strip()}")
        return proc.stdout

    def dropped(self) -> int:
        """Packets dropped by the loss rules since they were last set."""
        out = _run(
            [
                "ip",
                "netns",
                "exec",
                self._filter_ns,
                "nft",
                "list",
                "chain",
                self._FAMILY,
                self._TABLE,
                "forward",
            ]
        ).stdout
        return sum(int(n) for n in re.findall(r"counter packets (\d+)", out))

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for host in self._all_hosts():
            with contextlib.suppress(Exception):  # teardown carries on whatever happens
                host.stop()
        for ns in reversed(self._built):
            delete_named(ns)
        self._built.clear()
        atexit.unregister(self.close)

    def namespaces(self) -> list[str]:
        """This topology's namespaces that exist now (empty after teardown)."""
        return [ns for ns in _namespaces() if ns.startswith(self.prefix + "-")]


_T = TypeVar("_T", bound=_Topology)


class Lan(_Topology):
    """K hosts on one switch. A context manager: everything it made is gone after ``with``."""

    _FAMILY = "bridge"
    _TABLE = _LOSS_TABLE

    def __init__(self, hosts: int | Iterable[str]) -> None:
        super().__init__()
        names = [f"h{i + 1}" for i in range(hosts)] if isinstance(hosts, int) else list(hosts)
        if not names or len(set(names)) != len(names):
            raise ValueError("a LAN needs at least one host and unique host names")
        if len(names) > 200:
            raise ValueError("at most 200 hosts (one /24)")
        self.switch = f"{self.prefix}-sw"
        self.hosts: dict[str, Host] = {
            n: Host(n, f"{self.prefix}-h{i}", self.switch, f"p{i}", f"{SUBNET}.{10 + i}")
            for i, n in enumerate(names, start=1)
        }
        self.loss = 0
        self._loss: dict[str | None, int] = {}

    def __getitem__(self, name: str) -> Host:
        return self.hosts[name]

    def _all_hosts(self) -> Iterable[Host]:
        return self.hosts.values()

    def _build(self) -> None:
        self._switch(self.switch)
        self._loss_table(self.switch)
        self._add_hosts()

    # ------------------------------------------------------------------ faults
    def set_loss(self, percent: int | None, host: str | None = None) -> None:
        """Drop ``percent`` % of the frames the switch forwards, each frame copy drawn independently.

        With ``host``, only the frames the switch forwards *to* that host (a bad port or cable
        towards it); that rule comes first, so it overrides the LAN-wide one for that host, and
        ``percent=None`` removes it again.
        """
        if host is not None and host not in self.hosts:
            raise KeyError(host)
        if percent is None:
            if host is None:
                raise ValueError("percent=None only removes a host's own loss rule")
            self._loss.pop(host, None)
        elif not 0 <= percent <= 100:
            raise ValueError("loss is a percentage, 0..100")
        else:
            self._loss[host] = percent
        script = f"flush chain bridge {_LOSS_TABLE} forward\n"
        for target, pct in sorted(self._loss.items(), key=lambda kv: kv[0] is None):
            if not pct and target is None:
                continue
            match = f'oifname "{self.hosts[target].port}" ' if target is not None else ""
            verdict = (
                "accept"
                if not pct
                else "counter drop"
                if pct >= 100
                else f"numgen random mod 100 < {pct} counter drop"
            )
            script += f"add rule bridge {_LOSS_TABLE} forward {match}{verdict}\n"
        self._nft(script)
        self.loss = self._loss.get(None, 0)

    def cut(self, name: str) -> None:
        """Cut a host off the switch: its interface goes down (see :meth:`Host.link_down`)."""
        self.hosts[name].link_down()

    def restore(self, name: str) -> None:
        self.hosts[name].link_up()


class Wan(_Topology):
    """Sites of hosts behind one core router. A context manager: nothing is left after ``with``."""

    _FAMILY = "inet"
    _TABLE = "antalate_wan"

    def __init__(self, sites: Mapping[str, Sequence[str]]) -> None:
        super().__init__()
        self.core = f"{self.prefix}-core"
        self.sites = list(sites)
        self.site_index = {s: i + 1 for i, s in enumerate(self.sites)}
        self.hosts: dict[tuple[str, str], Host] = {}
        for site, names in sites.items():
            net = f"{WAN_SUBNET}.{self.site_index[site]}"
            for k, name in enumerate(names, start=1):
                self.hosts[(site, name)] = Host(
                    name,
                    f"{self.prefix}-{site}{k}",
                    f"{self.prefix}-sw{site}",
                    f"p{k}",
                    f"{net}.{10 + k}",
                    f"{net}.1",
                )
        self._loss: dict[str, int] = {}

    def __getitem__(self, key: tuple[str, str]) -> Host:
        return self.hosts[key]

    def _all_hosts(self) -> Iterable[Host]:
        return self.hosts.values()

    def _build(self) -> None:
        core = self._namespace(self.core)
        _run(["ip", "netns", "exec", core, "sysctl", "-qw", "net.ipv4.ip_forward=1"])
        for site in self.sites:
            sw = self._switch(f"{self.prefix}-sw{site}")
            uplink = f"s{site}"
            _run(
                [
                    "ip",
                    "-n",
                    core,
                    "link",
                    "add",
                    uplink,
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
            _run(
                ["ip", "-n", core, "addr", "add", f"{WAN_SUBNET}.{self.site_index[site]}.1/24", "dev", uplink]
            )
            _run(["ip", "-n", core, "link", "set", uplink, "up"])
        self._add_hosts()
        self._loss_table(core)

    def set_loss(self, site: str, percent: int) -> None:
        """Drop ``percent`` % of the packets through ``site``'s uplink, both ways (0 removes it)."""
        if site not in self.site_index:
            raise KeyError(site)
        if not 0 <= percent <= 100:
            raise ValueError("loss is a percentage, 0..100")
        self._loss[site] = percent
        script = f"flush chain inet {self._TABLE} forward\n"
        for s, pct in self._loss.items():
            if not pct:
                continue
            verdict = "counter drop" if pct >= 100 else f"numgen random mod 100 < {pct} counter drop"
            for hook in ("iifname", "oifname"):
                script += f'add rule inet {self._TABLE} forward {hook} "s{s}" {verdict}\n'
        self._nft(script)

    def cut(self, site: str) -> None:
        self.set_loss(site, 100)

    def restore(self, site: str) -> None:
        self.set_loss(site, 0)
