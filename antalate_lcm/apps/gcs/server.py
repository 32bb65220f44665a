"""``antalate mavlink-gcs CONFIG``: every agent as a MAVLink vehicle on one UDP endpoint (docs/tools.md).

A node on the bus (it hears TELEMETRY, MC_STATE, HLC_STATE and HLC_ERROR of every agent, signed when
the swarm has a key) turns what it hears into MAVLink (``view.GcsView``) and sends it through one
pymavlink UDP connection, one MAVLink encoder per system id, so each vehicle has its own sequence
numbers. A thread reads what the ground station sends and hands commands to the node's thread.

Commands are off by default: a TAKEOFF, LAND or RTL from the ground station is answered DENIED with a
STATUSTEXT saying why. With ``--commands`` each becomes an operator command signed with the config's
swarm key (one is required), sent as the console sends it (a fresh seq, resent with the same seq
until the MCs acknowledge it, at most three times) and answered ACCEPTED by each vehicle it went to.
"""

from __future__ import annotations

import logging
import random
import signal
import threading
import time
from dataclasses import dataclass, field
from types import FrameType
from typing import TYPE_CHECKING, Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.apps.gcs.view import GcsRefusal, GcsView, OperatorRequest
from antalate_lcm.base.deprecation import renamed_attribute
from antalate_lcm.base.errors import AntalateError
from antalate_lcm.core.config import Config
from antalate_lcm.core.node import Context, Node, NodeSettings, TopicMatch
from antalate_lcm.msgs import mc_state_t, operator_cmd_t

log = logging.getLogger("antalate.gcs")

WATCHED = ("TELEMETRY", "MC_STATE", "HLC_STATE", "HLC_ERROR")
#: Sends of one operator command (the first and two resends, a second apart) unless every MC it went
#: to acknowledged it before.
SENDS = 3
COMMANDS_OFF = "GCS commands are off (antalate mavlink-gcs --commands)"


@dataclass
class _Pending:
    topic: str
    msg: operator_cmd_t
    fields: dict[str, str]
    waiting: set[str]
    sends: int = 1


@dataclass
class GcsStats:
    commands_in: int = 0
    commands_sent: int = 0
    refused: int = 0
    bad_packets: int = 0
    sent: dict[str, int] = field(default_factory=dict)


class GcsNode(Node):
    kind = "gcs"

    if not TYPE_CHECKING:  # the old name, one release (issue #26's vocabulary); mypy sees only `ground`
        link = renamed_attribute("ground")

    def __init__(
        self,
        settings: NodeSettings,
        context: Context,
        view: GcsView,
        ground: Any,
        *,
        commands: bool,
        clock: Any = time.monotonic,
    ) -> None:
        super().__init__(settings, context)
        self.view = view
        #: The pymavlink connection to the ground station(s): not a "link" (docs/architecture.md,
        #: "Vocabulary": that is an adapter's I/O with its vehicle), the GCS's side of the picture.
        self.ground = ground
        self.commands = commands
        self.clock = clock
        self.stats = GcsStats()
        self._encoders: dict[int, Any] = {}
        self._boot = clock()
        self._seq = random.SystemRandom().randint(1, 2**30)
        self._pending: dict[int, _Pending] = {}

    def on_start(self) -> None:
        for topic in WATCHED:
            self.subscribe_all(topic, self._on_agent)
        self.create_timer(1.0, self._tick, first_delay=0.2)

    def _send(self, sysid: int, msg: Any) -> None:
        encoder = self._encoders.get(sysid)
        if encoder is None:
            encoder = self._encoders[sysid] = mav.MAVLink(self.ground, srcSystem=sysid, srcComponent=1)
        try:
            encoder.send(msg)
        except OSError as exc:  # no ground station yet (udpin before its first packet), or a dead route
            log.debug("cannot send %s: %s", msg.get_type(), exc)
            return
        kind = msg.get_type()
        self.stats.sent[kind] = self.stats.sent.get(kind, 0) + 1

    def _on_agent(self, msg: Any, match: TopicMatch) -> None:
        agent = match.fields.get("agent") or str(msg.header.agent)
        now = self.clock()
        placed = len(self.view.vehicles)
        for sysid, out in self.view.on_message(agent, msg, now, int((now - self._boot) * 1000)):
            self._send(sysid, out)
        if len(self.view.vehicles) > placed:  # said once per agent: which vehicle is which in the GCS
            print(f"agent {agent} is MAVLink system {self.view.vehicles[agent].sysid}", flush=True)
        if isinstance(msg, mc_state_t):
            pending = self._pending.get(int(msg.last_command_seq))
            if pending is not None:
                pending.waiting.discard(agent)

    def _tick(self) -> None:
        for sysid, out in self.view.tick(self.clock()):
            self._send(sysid, out)
        for seq, p in list(self._pending.items()):
            if not p.waiting or p.sends >= SENDS:
                del self._pending[seq]
                continue
            p.sends += 1
            self.publish(p.topic, p.msg, seq=seq, **p.fields)

    # ------------------------------------------------------------------ from the ground station
    def on_gcs(self, msg: Any) -> None:
        """A COMMAND_LONG or SET_MODE from the ground station (on the node's thread)."""
        now = self.clock()
        params: tuple[float, ...]
        if msg.get_type() == "SET_MODE":
            command, params = mav.MAV_CMD_DO_SET_MODE, (1.0, float(msg.custom_mode))
        else:
            command = int(msg.command)
            params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        req = self.view.request(int(msg.target_system), command, params, now)
        if req is None:
            return  # for a vehicle that is not ours: its own autopilot answers
        self.stats.commands_in += 1
        vehicles = self.view.targets(int(msg.target_system), now)
        if isinstance(req, GcsRefusal) or not self.commands:
            result, text = (
                (req.result, req.text)
                if isinstance(req, GcsRefusal)
                else (mav.MAV_RESULT_DENIED, COMMANDS_OFF)
            )
            self.stats.refused += 1
            log.warning(
                "refused a ground station's command %d for %s: %s", command, [v.name for v in vehicles], text
            )
            for v in vehicles:
                self._send(v.sysid, mav.MAVLink_command_ack_message(command, result))
                self._send(v.sysid, self.view.statustext(mav.MAV_SEVERITY_WARNING, text))
            return
        self._operator(req, vehicles=[v.name for v in vehicles])
        for v in vehicles:
            self._send(v.sysid, mav.MAVLink_command_ack_message(command, mav.MAV_RESULT_ACCEPTED))

    def _operator(self, req: OperatorRequest, *, vehicles: list[str]) -> None:
        self._seq += 1
        msg = operator_cmd_t()
        msg.command = int(req.command)
        msg.target = req.target
        msg.altitude = float(req.altitude)
        topic, fields = ("OPERATOR_CMD", {"agent": req.target}) if req.target else ("SWARM_OPERATOR_CMD", {})
        self.publish(topic, msg, seq=self._seq, **fields)
        self._pending[self._seq] = _Pending(topic, msg, fields, set(vehicles))
        self.stats.commands_sent += 1
        log.info(
            "ground station %s -> operator %s to %s (seq %d, signed)",
            req.command.name,
            req.command.name,
            req.target or "every agent",
            self._seq,
        )


def _reader(ground: Any, node: GcsNode, stop: threading.Event) -> None:
    """The ground station's packets (on this thread); commands go to the node's thread."""
    while not stop.is_set():
        try:
            msg = ground.recv_match(blocking=True, timeout=0.5)
        except Exception as exc:  # noqa: BLE001 - a hostile packet must not end the reader
            node.stats.bad_packets += 1
            log.debug("unreadable packet from the ground station: %s", exc)
            continue
        if msg is None:
            continue
        kind = msg.get_type()
        if kind == "BAD_DATA":
            node.stats.bad_packets += 1
        elif kind in ("COMMAND_LONG", "SET_MODE"):
            node.context.executor.call_soon(node.on_gcs, msg)


def serve(
    config: Config,
    *,
    endpoint: str,
    commands: bool,
    no_auth: bool,
    sysid_base: int,
    hide_autopilots: frozenset[str],
) -> int:
    """Present the swarm on ``endpoint`` (pymavlink's ``udpin:HOST:PORT`` or ``udpout:HOST:PORT``)
    until Ctrl-C or SIGTERM."""
    from operator_tui.web import is_loopback

    host = endpoint.split(":")[1]
    if not is_loopback(host) and not no_auth:
        raise AntalateError(
            f"refusing to serve MAVLink on {host}: MAVLink carries no credential here, so anyone who "
            f"reaches the port sees the swarm{' and commands it' if commands else ''}. Use 127.0.0.1 "
            "(and tunnel), or pass --no-auth"
        )
    if commands and not config.security.swarm_key:
        raise AntalateError(
            f"--commands needs [security] swarm_key in {config.source}: the commands it sends are signed "
            "operator commands (docs/security.md)"
        )
    try:
        view = GcsView(sysid_base=sysid_base, hide_autopilots=hide_autopilots)
    except ValueError as exc:
        raise AntalateError(str(exc)) from None
    try:
        ground = mavutil.mavlink_connection(endpoint, source_system=255, dialect="ardupilotmega")
    except OSError as exc:
        raise AntalateError(f"cannot open {endpoint}: {exc.strerror or exc}") from None
    signalled: list[int] = []

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        signalled.append(signum)  # only a flag: the main thread polls (runtime/launch.py says why)

    previous = signal.signal(signal.SIGTERM, on_signal)
    context = Context.create(config)
    node = GcsNode(NodeSettings.from_config(config), context, view, ground, commands=commands)
    stop = threading.Event()
    reader = threading.Thread(target=_reader, args=(ground, node, stop), name="gcs-reader", daemon=True)
    try:
        context.buses.open()
        context.executor.start()
        node.start()
        reader.start()
        mode = "commands ON (signed)" if commands else "read-only: commands refused"
        print(
            f"presenting the swarm as MAVLink vehicles on {endpoint} from system id {sysid_base} ({mode}); Ctrl-C stops",
            flush=True,
        )
        try:
            while not signalled:
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
    finally:
        stop.set()
        node.stop()
        context.close()
        if reader.is_alive():
            reader.join(timeout=2)
        ground.close()
        signal.signal(signal.SIGTERM, previous)
    print(
        f"vehicles: {', '.join(f'{v.name}={v.sysid}' for v in view.vehicles.values()) or 'none heard'}",
        flush=True,
    )
    st = node.stats
    sent = ", ".join(f"{n} {kind}" for kind, n in sorted(st.sent.items())) or "nothing"
    print(
        f"ground station: {st.commands_in} command(s) for the swarm, {st.commands_sent} sent as operator "
        f"commands, {st.refused} refused; {st.bad_packets} unreadable packet(s); sent {sent}",
        flush=True,
    )
    return 0
