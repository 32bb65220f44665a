"""The operator laptop of the LAN tests: a console without a terminal, driven by JSON lines on stdin.

    python -m tests.lan.lan_operator CONFIG [--stale-after 2]

It is an ordinary antalate :class:`~antalate_lcm.node.Node` on the config's LAN bus, and sends and
tracks commands with the operator console's own :class:`operator_tui.commands.CommandTracker`
(seq per command, ack = ``mc_state_t.last_command_seq``, resend with the same seq until every
expected agent acknowledged) and :class:`~operator_tui.commands.DirectionControl` (the direction is a
state, repeated every second), so what the tests prove is what the console does.

Requests, one JSON object a line; one JSON reply line each:

* ``{"op": "command", "command": "TAKEOFF", "target": "", "altitude": 3}`` -> ``{"seq": S}``;
  an empty target broadcasts and expects an ack from every agent heard within ``stale_after``.
* ``{"op": "direction", "azimuth": 90, "speed": 1, "active": true}`` (to every agent).
* ``{"op": "status"}`` -> ``{"agents": {name: {...}}, "stale": [...], "commands": [...]}``.
* ``{"op": "quit"}``.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from typing import Any

from antalate_lcm.config import Config, load_config
from antalate_lcm.msgs import direction_cmd_t, hlc_state_t, mc_state_t, operator_cmd_t, telemetry_t
from antalate_lcm.node import Context, Node, TopicMatch
from antalate_lcm.vocabulary import HlcState, McState
from operator_tui.commands import COMMANDS, CommandTracker, DirectionControl, Status


@dataclass
class AgentView:
    mc: str | None = None
    mc_heard: float | None = None
    last_command_seq: int = 0
    hlc: str | None = None
    lat: float = 0.0
    lon: float = 0.0
    alt: float = 0.0
    in_air: bool = False
    tel_heard: float | None = None


class LanOperator(Node):
    kind = "operator"

    def __init__(self, config: Config, context: Context, *, stale_after: float = 2.0) -> None:
        super().__init__(config, context)
        self.stale_after = stale_after
        self.tracker = CommandTracker(resend_interval=1.0, timeout=30.0)
        self.direction = DirectionControl(repeat_interval=1.0)
        self.agents: dict[str, AgentView] = {}
        self.updates: list[str] = []

    def on_start(self) -> None:
        self.subscribe_all("MC_STATE", self._on_mc)
        self.subscribe_all("HLC_STATE", self._on_hlc)
        self.subscribe_all("TELEMETRY", self._on_telemetry)
        self.create_timer(0.1, self._tick)

    # ------------------------------------------------------------------ inputs
    def _view(self, match: TopicMatch, msg: Any) -> AgentView:
        name = match.fields.get("agent") or msg.header.agent
        return self.agents.setdefault(name, AgentView())

    def _on_mc(self, msg: mc_state_t, match: TopicMatch) -> None:
        view = self._view(match, msg)
        view.mc = McState(msg.state).name if msg.state in McState._value2member_map_ else f"?{msg.state}"
        view.mc_heard = self.now
        view.last_command_seq = msg.last_command_seq
        name = match.fields.get("agent") or msg.header.agent
        self.updates.extend(u.text for u in self.tracker.observe(name, msg.last_command_seq, self.now))

    def _on_hlc(self, msg: hlc_state_t, match: TopicMatch) -> None:
        view = self._view(match, msg)
        view.hlc = HlcState(msg.state).name if msg.state in HlcState._value2member_map_ else f"?{msg.state}"

    def _on_telemetry(self, msg: telemetry_t, match: TopicMatch) -> None:
        view = self._view(match, msg)
        view.lat, view.lon, view.alt, view.in_air = msg.lat, msg.lon, msg.alt, msg.in_air
        view.tel_heard = self.now

    # ------------------------------------------------------------------ stale detection
    def age(self, name: str) -> float | None:
        heard = self.agents[name].mc_heard
        return None if heard is None else self.now - heard

    def is_stale(self, name: str) -> bool:
        age = self.age(name) if name in self.agents else None
        return age is None or age > self.stale_after

    # ------------------------------------------------------------------ outputs
    def _tick(self) -> None:
        resend, updates = self.tracker.tick(
            self.now, lambda a: self.agents[a].mc if a in self.agents else None, self.is_stale
        )
        for cmd in resend:
            self._send_command(cmd.command, cmd.target, cmd.altitude, cmd.seq)
        self.updates.extend(u.text for u in updates)
        if self.direction.due(self.now):
            self._send_direction()

    def _send_command(self, command: str, target: str, altitude: float, seq: int) -> None:
        msg = operator_cmd_t()
        msg.command = COMMANDS[command]
        msg.target = target
        msg.altitude = altitude
        if target:
            self.publish("OPERATOR_CMD", msg, seq=seq, agent=target)  # Node.publish signs with the swarm key
        else:
            self.publish("SWARM_OPERATOR_CMD", msg, seq=seq)

    def _send_direction(self) -> None:
        msg = direction_cmd_t()
        msg.active = self.direction.active
        msg.azimuth = self.direction.azimuth
        msg.speed = self.direction.speed
        self.publish("SWARM_DIRECTION_CMD", msg)
        self.direction.sent("", self.now)

    def command(self, command: str, target: str = "", altitude: float = 0.0) -> int:
        live = [a for a in self.agents if not self.is_stale(a)]
        cmd = self.tracker.new(command, target, self.now, expected=live, altitude=altitude)
        self._send_command(cmd.command, cmd.target, cmd.altitude, cmd.seq)
        return cmd.seq

    def set_direction(self, azimuth: float, speed: float, active: bool) -> None:
        self.direction.azimuth, self.direction.speed, self.direction.active = azimuth % 360.0, speed, active
        self._send_direction()

    def status(self) -> dict[str, Any]:
        now = self.now
        agents = {
            name: {
                "mc": v.mc,
                "hlc": v.hlc,
                "last_command_seq": v.last_command_seq,
                "mc_age": None if v.mc_heard is None else now - v.mc_heard,
                "tel_age": None if v.tel_heard is None else now - v.tel_heard,
                "lat": v.lat,
                "lon": v.lon,
                "alt": v.alt,
                "in_air": v.in_air,
            }
            for name, v in sorted(self.agents.items())
        }
        commands = [
            {
                "seq": c.seq,
                "command": c.command,
                "target": c.target,
                "status": c.status.value,
                "sends": c.sends,
                "expected": sorted(c.expected),
                "acked": sorted(c.acked),
                "superseded": sorted(c.superseded),
                "reason": c.reason,
            }
            for c in [*self.tracker.done, *self.tracker.pending.values()]
        ]
        return {
            "agents": agents,
            "stale": sorted(a for a in self.agents if self.is_stale(a)),
            "commands": sorted(commands, key=lambda c: c["seq"]),
            "pending": sum(1 for c in commands if c["status"] == Status.PENDING.value),
            "direction_sends": self.direction.sends,
            "updates": list(self.updates),
        }


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.lan.lan_operator")
    parser.add_argument("config")
    parser.add_argument("--stale-after", type=float, default=2.0)
    args = parser.parse_args()
    config = load_config(args.config)
    context = Context.create(config)
    context.bus.open()
    context.executor.start()
    node = LanOperator(config, context, stale_after=args.stale_after)
    node.start()
    run = context.executor.run_sync
    print(json.dumps({"ready": True}), flush=True)
    try:
        for line in sys.stdin:
            req = json.loads(line)
            op = req.get("op")
            if op == "command":
                command, target, alt = req["command"], req.get("target", ""), float(req.get("altitude", 0.0))
                reply: dict[str, Any] = {"seq": run(lambda: node.command(command, target, alt))}  # noqa: B023 - run at once
            elif op == "direction":
                az, speed, active = (
                    float(req["azimuth"]),
                    float(req.get("speed", 1.0)),
                    bool(req.get("active", True)),
                )
                run(lambda: node.set_direction(az, speed, active))  # noqa: B023 - run at once
                reply = {"ok": True}
            elif op == "status":
                reply = run(node.status)
            elif op == "quit":
                print(json.dumps({"ok": True}), flush=True)
                break
            else:
                reply = {"error": f"unknown op {op!r}"}
            print(json.dumps(reply), flush=True)
    finally:
        node.stop()
        context.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
