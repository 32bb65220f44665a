"""The security suite's swarm: a real station, real agents and two peers in one private network namespace.

Everything here is what a defender would run in the field, started the way a user starts it
(``antalate station``, ``antalate agent``, ``antalate mc``/``hlc`` as separate processes), plus:

* ``attacker``: a process on the same network that knows no key (tests/security/peer.py);
* ``operator``: the legitimate, keyed operator, also the witness of genuine (signed) messages.

What "nothing moved" is judged by never comes from the network an attacker can write to: the
simulated vehicle's own state file (position, armed, in air) and the nodes' logs (every MC and HLC
transition is logged with its cause).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

from antalate_lcm.station._auth import new_api_key, registration_key, sha256_hex
from tests.harness.agents import FAST_SIM, AgentProcesses
from tests.harness.jsonl import JsonLinesProcess
from tests.harness.netns import NetNamespace
from tests.harness.polling import wait_for
from tests.harness.process import stop_process
from tests.harness.tls import make_tls

LAN = "udpm://239.255.76.67:7667?ttl=0"
LOCAL = "udpm://239.255.76.68:7668?ttl=0"
STATION_PORT = 18080
#: The swarm key the defenders share. Never given to the attacker process.
SWARM_KEY = "swarm-" + secrets.token_hex(16)
#: Replay window of every node. Generous on purpose: a replay guard must not rely on the window being
#: shorter than an MC restart, and a loaded test machine must not make genuine commands look stale.
WINDOW = 30.0
HOME = (32.7767, 35.0231)
#: Self-check of the suite: ``ANTALATE_SECURITY_DISARMED=1`` runs the same swarm with no swarm key
#: (``[security] insecure = true``), no registration key, no TLS and no MAVLink signing. The attacks
#: those defences stop must then succeed (their tests fail): a test that passes disarmed proves
#: nothing about the defence it claims to test. See README.md for the defences that stay on.
DISARMED = os.environ.get("ANTALATE_SECURITY_DISARMED") == "1"


class NotJudged(Exception):
    """The test could not set up its attack, or the machine starved a node: no verdict on the attack.

    Not an AssertionError, so the summary counts it apart from attacks that succeeded (the test
    still fails)."""


_TRANSITION = re.compile(r"antalate\.(mc|hlc)\.([\w.-]+): (\w+) -> (\w+) on (.*)$")


class PeerClient(JsonLinesProcess):
    """Client side of tests/security/peer.py; ``station`` is the station's base URL."""

    def __init__(self, proc: subprocess.Popen[str], what: str, station: str) -> None:
        super().__init__(proc, what)
        self.station = station

    def _ok(self, **req: Any) -> dict[str, Any]:
        reply = self.call(**req)
        assert reply["ok"], f"{self.what}: {req['op']} failed: {reply.get('error')}"
        return reply

    def publish(
        self,
        channel: str,
        type_name: str,
        *,
        sign: bool = False,
        count: int = 1,
        stamp: bool = True,
        **fields: Any,
    ) -> bytes:
        """Encode and send a message; returns its bytes. ``stamp`` sets header.utime to now."""
        reply = self._ok(
            op="publish", channel=channel, type=type_name, fields=fields, sign=sign, count=count, stamp=stamp
        )
        return bytes.fromhex(reply["hex"])

    def batch(self, items: list[tuple[str, bytes]], gap: float = 0.0) -> None:
        self._ok(op="batch", items=[{"channel": c, "hex": d.hex()} for c, d in items], gap=gap)

    def replay(
        self, channel: str, type_name: str, pick: str = "last", since: int = 0, **where: Any
    ) -> dict[str, Any]:
        """Resend, byte for byte, a message recorded off the network."""
        reply = self._ok(op="replay", channel=channel, type=type_name, where=where, pick=pick, since=since)
        msg: dict[str, Any] = reply["msg"]
        return msg

    def capture(self, channel: str, type_name: str, since: int = 0, **where: Any) -> bytes:
        """The bytes of the last message recorded on ``channel`` matching ``where``."""
        reply = self._ok(op="capture", channel=channel, type=type_name, where=where, pick="last", since=since)
        return bytes.fromhex(reply["hex"])

    def wait(
        self,
        channel: str,
        type_name: str,
        timeout: float = 15,
        since: int = 0,
        genuine: bool = False,
        **where: Any,
    ) -> dict[str, Any] | None:
        reply = self.call(
            op="wait",
            channel=channel,
            type=type_name,
            where=where,
            timeout=timeout,
            since=since,
            genuine=genuine and not DISARMED,
        )
        return reply.get("msg") if reply["ok"] else None

    def history(
        self, channel: str, type_name: str, since: int = 0, genuine: bool = False
    ) -> list[dict[str, Any]]:
        reply = self._ok(
            op="history", channel=channel, type=type_name, since=since, genuine=genuine and not DISARMED
        )
        msgs: list[dict[str, Any]] = reply["msgs"]
        return msgs

    def mark(self) -> int:
        return int(self._ok(op="mark")["index"])

    def sniff_start(self, port: int) -> str | None:
        """Capture every TCP payload to or from ``port`` on lo (a packet socket: what a host on a
        shared link, or anyone with a tap, sees). Returns why it cannot, or None."""
        reply = self.call(op="sniff_start", port=port)
        return None if reply["ok"] else str(reply.get("error"))

    def sniff_take(self) -> bytes:
        return bytes.fromhex(self._ok(op="sniff_take")["hex"])

    def udp_open(self) -> int:
        return int(self._ok(op="udp_open")["port"])

    def udp_send(self, port: int, datagrams: list[bytes], gap: float = 0.0) -> None:
        self._ok(op="udp_send", host="127.0.0.1", port=port, hexes=[d.hex() for d in datagrams], gap=gap)

    def udp_recv(self, since: int = 0) -> tuple[list[bytes], int]:
        reply = self._ok(op="udp_recv", since=since)
        return [bytes.fromhex(h) for h in reply["hexes"]], int(reply["index"])

    def http(
        self,
        method: str,
        path: str,
        json_body: Any = None,
        *,
        headers: dict[str, str] | None = None,
        bodies: list[Any] | None = None,
        content: str | None = None,
        source: str | None = None,
    ) -> list[dict[str, Any]]:
        """One request (or one per entry of ``bodies``); ``source``: send from this local address."""
        url = path if path.startswith("http") else self.station + path
        reply = self._ok(
            op="http",
            method=method,
            url=url,
            json=json_body,
            headers=headers,
            bodies=bodies,
            content=content,
            source=source,
        )
        responses: list[dict[str, Any]] = reply["responses"]
        return responses

    def http1(self, method: str, path: str, json_body: Any = None, **kw: Any) -> dict[str, Any]:
        return self.http(method, path, json_body, **kw)[0]


@dataclass
class Vehicle:
    """The simulated vehicle as its autopilot keeps it (the sim's state file), not as anyone reports it."""

    north: float
    east: float
    alt: float
    armed: bool
    in_air: bool
    mode: str
    phase: str
    saved_at: float
    vn: float = 0.0
    ve: float = 0.0

    @property
    def speed(self) -> float:
        """Horizontal ground speed, m/s."""
        return float((self.vn**2 + self.ve**2) ** 0.5)

    def distance(self, other: Vehicle) -> float:
        return float(
            ((self.north - other.north) ** 2 + (self.east - other.east) ** 2 + (self.alt - other.alt) ** 2)
            ** 0.5
        )


class AgentRun(AgentProcesses):
    """One agent: its config file, its node processes (or a share of an ``antalate agent`` process),
    its simulated vehicle's state file."""

    def __init__(self, swarm: Swarm, name: str, doc: dict[str, Any]) -> None:
        self.swarm = swarm
        self.state_file = swarm.tmp / f"{name}-vehicle.json"
        hlc = doc.setdefault("hlc", {})
        if hlc.get("autopilot", "sim") == "sim":
            hlc.setdefault("autopilot_params", {})["state_file"] = str(self.state_file)
        super().__init__(swarm.netns, swarm.tmp, doc)
        #: The ``antalate agent`` process this agent shares with others, if it runs in one.
        self.shared: subprocess.Popen[str] | None = None

    def log(self, node: str | None = None) -> str:
        """As `AgentProcesses.log`; every log also holds this agent's lines of a shared process."""
        return super().log(node) + ("" if node else self.swarm.shared_log(self.name))

    def lines(self) -> list[str]:
        """This agent's log lines (a shared ``antalate agent`` log holds several agents)."""
        tag = re.compile(rf"antalate\.\w+\.{re.escape(self.name)}[:.]")
        return [ln for ln in self.log().splitlines() if tag.search(ln)]

    def transitions(self, node: str = "mc") -> list[tuple[str, str, str]]:
        """(from, to, cause) of every logged transition of this agent's MC (or HLC), in order."""
        out = []
        for line in self.log().splitlines():
            m = _TRANSITION.search(line)
            if m and m.group(1) == node and m.group(2) == self.name:
                out.append((m.group(3), m.group(4), m.group(5)))
        return out

    def mc_state(self) -> str | None:
        t = self.transitions("mc")
        return t[-1][1] if t else None

    def wait_mc(self, state: str, timeout: float = 30.0, after: int = 0) -> list[tuple[str, str, str]]:
        """Poll the MC log until it has entered ``state`` (at transition index >= ``after``)."""
        hit = wait_for(lambda: any(to == state for _, to, _ in self.transitions("mc")[after:]), timeout, 0.1)
        if not hit:
            raise NotJudged(f"{self.name}: MC never reached {state}; transitions {self.transitions('mc')}")
        return self.transitions("mc")

    def vehicle(self) -> Vehicle:
        """The vehicle's state, read from the sim's state file (fresh within a second)."""

        def read() -> dict[str, Any] | None:
            try:
                data = json.loads(self.state_file.read_text())
            except (OSError, ValueError):
                return None
            return data if time.time() - data["saved_at"] < 3.0 else None

        data = wait_for(read, 15.0, 0.1)
        if not data:
            raise NotJudged(f"{self.name}: no fresh vehicle state in {self.state_file}")
        return Vehicle(
            data["north"],
            data["east"],
            data["alt"],
            bool(data["armed"]),
            bool(data["in_air"]),
            data["mode"],
            data["phase"],
            data["saved_at"],
            data["vn"],
            data["ve"],
        )

    def vehicle_after(self, t: float) -> Vehicle:
        """The vehicle's state as saved after wall time ``t`` (so it reflects what happened until then)."""
        v = wait_for(lambda: (lambda s: s if s.saved_at > t else None)(self.vehicle()), 15.0, 0.1)
        if not v:
            raise NotJudged(f"{self.name}: the vehicle state was not saved after {t}")
        return v


class Swarm:
    """The station, the agents, the attacker and the operator in one namespace."""

    def __init__(self, netns: NetNamespace, tmp: Path) -> None:
        self.netns = netns
        self.tmp = tmp
        self.agents: dict[str, AgentRun] = {}
        self._shared: dict[str, Path] = {}
        self.station: subprocess.Popen[str] | None = None
        self.station_log = tmp / "station.log"
        self.station_db = tmp / "station.sqlite"
        self.api_keys: dict[str, str] = {}
        #: (CA, certificate, key) when the station serves HTTPS: always, unless openssl is missing
        #: (then the TLS attacks skip) or the suite runs disarmed.
        self.tls = None if DISARMED or shutil.which("openssl") is None else make_tls(tmp)
        self.station_url = f"{'https' if self.tls else 'http'}://127.0.0.1:{STATION_PORT}"
        self.peers: list[PeerClient] = []
        self.attacker: PeerClient | None = None
        self.operator: PeerClient | None = None
        self._op_seq = int(time.time()) % 100_000 * 10

    # -- processes ------------------------------------------------------------------------------
    def start_station(self) -> None:
        """``antalate station --config station.toml``: an operator key, a read-only key, the
        registration key derived from the swarm key, the default rate limits."""
        self.api_keys = {"operator": new_api_key(), "read-only": new_api_key()}
        doc: dict[str, Any] = {
            "station": {
                "host": "127.0.0.1",
                "port": STATION_PORT,
                "db": str(self.station_db),
                **({"tls_cert": str(self.tls[1]), "tls_key": str(self.tls[2])} if self.tls else {}),
            },
            "api_keys": [
                {"name": f"{role}-person", "role": role, "sha256": sha256_hex(key)}
                for role, key in self.api_keys.items()
            ],
        }
        if not DISARMED:
            doc["station"]["registration_key"] = registration_key(SWARM_KEY)
        path = self.tmp / "station.toml"
        path.write_text(tomli_w.dumps(doc))
        out = open(self.station_log, "w")  # noqa: SIM115 - the process owns it
        self.station = self.netns.antalate(
            "station", "--config", str(path), stdout=out, stderr=subprocess.STDOUT
        )

    def auth(self, role: str) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.api_keys[role]}"}

    def station_text(self) -> str:
        return self.station_log.read_text(errors="replace")

    def agent(self, name: str, doc: dict[str, Any]) -> AgentRun:
        run = AgentRun(self, name, doc)
        self.agents[name] = run
        return run

    def start_agents_process(self, label: str, names: list[str]) -> subprocess.Popen[str]:
        """``antalate agent A.toml B.toml``: several agents, every node of each, in one process."""
        log = self.tmp / f"{label}.log"
        for name in names:
            self._shared[name] = log
        out = open(log, "w")  # noqa: SIM115 - the process owns it
        proc = self.netns.antalate(
            "agent", *(str(self.agents[n].path) for n in names), stdout=out, stderr=subprocess.STDOUT
        )
        for name in names:
            self.agents[name].shared = proc
        return proc

    def shared_log(self, name: str) -> str:
        path = self._shared.get(name)
        return path.read_text(errors="replace") if path is not None else ""

    def peer(
        self, what: str, key: str | None, source: str | None = None, ca: Path | None = None
    ) -> PeerClient:
        """A peer process; ``ca``: verify the station's certificate with it (else: no verification,
        as an attacker does not care whom it talks to)."""
        args = ["tests.security.peer", LAN, LOCAL, "--window", str(WINDOW)]
        if key is not None:
            args += ["--key", key]
        if source is not None:
            args += ["--source", source]
        if ca is not None:
            args += ["--ca", str(ca)]
        client = PeerClient(self.netns.peer(*args), what, self.station_url)
        self.peers.append(client)
        return client

    def close(self) -> None:
        """SIGTERM to every process at once, then wait for each (one by one would add their stop times)."""
        procs = [p for run in self.agents.values() for p in run.procs.values()]
        procs += [self.station] if self.station is not None else []
        procs += [peer.proc for peer in self.peers]
        for proc in procs:
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(proc.pid, signal.SIGTERM)
        for proc in procs:
            stop_process(proc)
        self.netns.close()

    # -- the legitimate operator ----------------------------------------------------------------
    def next_seq(self) -> int:
        self._op_seq += 1
        return self._op_seq


def agent_doc(
    name: str,
    state_dir: Path,
    *,
    sim: dict[str, Any] | None = None,
    home: tuple[float, float] = HOME,
    internal: str = "local",
    **sections: Any,
) -> dict[str, Any]:
    """An agent's config as a field user writes it: internal topics on the host-only ``local`` bus,
    what the operator sees also on ``lan``, a swarm key; the replay memory in ``state_dir``."""
    hlc = {
        "autopilot": "sim",
        "default_takeoff_altitude": 3.0,
        "link_timeout": 2.0,
        **sections.pop("hlc", {}),
    }
    hlc["autopilot_params"] = {**FAST_SIM, "home_lat": home[0], "home_lon": home[1], **(sim or {})}
    doc: dict[str, Any] = {
        "agent": {"name": name},
        "buses": {"lan": LAN, "local": LOCAL},
        "topics": {
            "default_bus": internal,
            "MC_STATE": [internal, "lan"],
            "HLC_STATE": [internal, "lan"],
            "TELEMETRY": [internal, "lan"],
            "HLC_ERROR": [internal, "lan"],
            "ARBITER": [internal, "lan"],
            "OPERATOR_CMD": ["lan", internal],
            "DIRECTION_CMD": ["lan", internal],
            "SWARM_OPERATOR_CMD": "lan",
            "SWARM_DIRECTION_CMD": "lan",
        },
        "hlc": hlc,
        "security": (
            {"swarm_key": "", "insecure": True}
            if DISARMED
            else {"swarm_key": SWARM_KEY, "window": WINDOW, "state_dir": str(state_dir)}
        ),
    }
    doc.update(sections)
    return doc


# ---------------------------------------------------------------------------------------------- helpers
OPERATOR = "operator"
MC_NAMES = {"TAKEOFF": 0, "LAND": 1, "RTL": 2}


def command(
    operator: PeerClient,
    swarm: Swarm,
    target: str,
    name: str,
    *,
    altitude: float = 0.0,
    channel: str | None = None,
    seq: int | None = None,
) -> bytes:
    """A genuine, signed operator command (what the operator console sends); returns its bytes."""
    return operator.publish(
        channel or f"{target}/OPERATOR_CMD",
        "operator_cmd_t",
        sign=True,
        header={"agent": OPERATOR, "seq": seq if seq is not None else swarm.next_seq()},
        command=MC_NAMES[name],
        target=target,
        altitude=altitude,
    )


def direction(
    operator: PeerClient, swarm: Swarm, target: str, azimuth: float, speed: float, active: bool = True
) -> bytes:
    return operator.publish(
        f"{target}/DIRECTION_CMD",
        "direction_cmd_t",
        sign=True,
        header={"agent": OPERATOR, "seq": swarm.next_seq()},
        active=active,
        azimuth=azimuth,
        speed=speed,
        target=target,
    )


@dataclass
class Baseline:
    """What an agent looked like before an attack: its vehicle and how many transitions were logged."""

    vehicle: Vehicle
    mc: int
    hlc: int
    t: float


def baseline(run: AgentRun) -> Baseline:
    return Baseline(
        run.vehicle_after(time.time()), len(run.transitions("mc")), len(run.transitions("hlc")), time.time()
    )


def settle(run: AgentRun, seconds: float = 1.0) -> Vehicle:
    """The vehicle once the attack had ``seconds`` to act (a takeoff climbs metres in that time)."""
    time.sleep(seconds)
    return run.vehicle_after(time.time())


def assert_unmoved(
    run: AgentRun, before: Baseline, *, tolerance: float = 0.3, still: bool = True, wait: float = 1.0
) -> Vehicle:
    """The attack changed nothing: the vehicle is where it was (armed/in air as it was) and neither the
    MC nor the HLC made a transition since ``before``. ``still=False`` only checks arm/air state and
    transitions (for a vehicle that legitimately moves on its own). ``wait``: how long the attack is
    given to act first (0 when the caller already waited, e.g. for several agents at once)."""
    after = settle(run, wait)
    new_mc = run.transitions("mc")[before.mc :]
    new_hlc = run.transitions("hlc")[before.hlc :]
    if (
        new_mc
        and not new_hlc
        and all(_watchdog(t) for t in new_mc)
        and after.distance(before.vehicle) <= tolerance
    ):
        # The MC's HLC watchdog fired and the MC resynchronised, nothing else happened: on a
        # heavily loaded machine a node was not scheduled for seconds. An attack does not do that.
        raise NotJudged(f"{run.name}: the MC lost and found its HLC (a starved process?): {new_mc}")
    assert not new_mc, f"{run.name}: the MC made transitions during the attack: {new_mc}"
    assert not new_hlc, f"{run.name}: the HLC made transitions during the attack: {new_hlc}"
    assert (after.armed, after.in_air) == (before.vehicle.armed, before.vehicle.in_air), (
        f"{run.name}: vehicle armed/in-air changed: before {before.vehicle}, after {after}"
    )
    if still:
        moved = after.distance(before.vehicle)
        assert moved <= tolerance, (
            f"{run.name}: the vehicle moved {moved:.2f} m: before {before.vehicle}, after {after}"
        )
    return after


def _watchdog(t: tuple[str, str, str]) -> bool:
    """An MC transition of its HLC watchdog: into HLC_LOST on its timer, or the resync out of it."""
    src, dst, cause = t
    return (dst == "HLC_LOST" and cause.startswith("timer")) or (
        src == "HLC_LOST" and cause.startswith("HLC state")
    )


def fly(swarm: Swarm, operator: PeerClient, name: str) -> AgentRun:
    """Take ``name`` to MISSION with a genuine signed TAKEOFF (no-op when it already is): its run."""
    run = swarm.agents[name]
    if run.mc_state() == "MISSION":
        return run
    n = len(run.transitions("mc"))
    command(operator, swarm, name, "TAKEOFF")
    run.wait_mc("MISSION", timeout=30, after=n)
    if not wait_for(lambda: run.vehicle().in_air, 15.0, 0.1):
        raise NotJudged(f"{name}: in MISSION but not in the air")
    return run
