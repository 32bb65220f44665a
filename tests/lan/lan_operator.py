"""The operator laptop of the LAN tests: a console without a terminal, driven by JSON lines on stdin.

    python -m tests.lan.lan_operator CONFIG [--stale-after 2]

It is the operator console without its terminal: the console's own node
(:class:`operator_tui.node.OperatorNode`: receiving, signed sending), board
(:class:`operator_tui.board.SwarmBoard`: who is live or stale), command tracker
(:class:`operator_tui.commands.CommandTracker`: seq per command, ack = ``mc_state_t.last_command_seq``,
resend with the same seq until every expected agent acknowledged) and direction control (the direction
is a state, repeated every second), so what the tests prove is what the console does.

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
from typing import Any

from antalate_lcm.core.config import load_config
from antalate_lcm.core.node import Context, NodeSettings
from operator_tui.board import SwarmBoard
from operator_tui.commands import CommandTracker, DirectionControl, Status
from operator_tui.node import OperatorNode


class LanOperator(OperatorNode):
    """The console's own parts without its terminal: :class:`~operator_tui.node.OperatorNode` receives
    and sends (signed), :class:`~operator_tui.board.SwarmBoard` says who is stale, the tracker and
    the direction control resend. Its refresh runs on the executor's timer instead of the UI's."""

    def __init__(self, settings: NodeSettings, context: Context, *, stale_after: float = 2.0) -> None:
        super().__init__(settings, context)
        self.board = SwarmBoard(stale_after=stale_after)
        self.tracker = CommandTracker(resend_interval=1.0, timeout=30.0)
        self.direction = DirectionControl(repeat_interval=1.0)
        self.updates: list[str] = []

    def on_start(self) -> None:
        super().on_start()
        self.create_timer(0.1, self.refresh)

    def refresh(self) -> None:
        """What the console's refresh does, but draw: fold in what arrived, mark the silent stale,
        resend what is unacknowledged and repeat the direction."""
        now, wall = self.clock(), self.wallclock()
        for item in self.drain():
            if item.unchanged:
                self.board.heard(item.topic, item.agent, item.received, wall)
                continue
            self.board.apply(item.topic, item.agent, item.msg, item.received, wall, item.fields)
            if item.topic == "MC_STATE":
                observed = self.tracker.observe(item.agent, item.msg.last_command_seq, now)
                self.updates.extend(u.text for u in observed)
        self.board.tick(now, wall)
        resend, updates = self.tracker.tick(now, self.board.mc_state_of, self.board.is_stale)
        for cmd in resend:
            self.send_operator_cmd(cmd.command, cmd.target, cmd.seq, altitude=cmd.altitude)
        self.updates.extend(u.text for u in updates)
        if self.direction.due(now) and self.direction.target is not None:
            self._send_direction(self.direction.target, now)

    def _send_direction(self, target: str, now: float) -> None:
        d = self.direction
        self.send_direction(active=d.active, azimuth=d.azimuth, speed=d.speed, target=target)
        d.sent(target, now)

    def command(self, command: str, target: str = "", altitude: float = 0.0) -> int:
        """A new command, as the console sends it: a broadcast expects every live agent's ack."""
        expected = self.board.live_names() if not target else [target]
        cmd = self.tracker.new(command, target, self.clock(), expected=expected, altitude=altitude)
        self.send_operator_cmd(command, target, cmd.seq, altitude=altitude)
        return cmd.seq

    def set_direction(self, azimuth: float, speed: float, active: bool) -> None:
        self.direction.azimuth, self.direction.speed, self.direction.active = azimuth % 360.0, speed, active
        self._send_direction("", self.clock())

    def status(self) -> dict[str, Any]:
        now = self.clock()
        agents: dict[str, Any] = {}
        for name in self.board.names():
            v = self.board.agents[name]
            mc_heard, tel_heard = v.heard.get("MC_STATE"), v.heard.get("TELEMETRY")
            tel = v.telemetry
            agents[name] = {
                "mc": v.mc_state,
                "hlc": v.hlc_state,
                "last_command_seq": v.last_command_seq or 0,
                "mc_age": None if mc_heard is None else now - mc_heard,
                "tel_age": None if tel_heard is None else now - tel_heard,
                "lat": tel.lat if tel else 0.0,
                "lon": tel.lon if tel else 0.0,
                "alt": tel.alt if tel else 0.0,
                "in_air": tel.in_air if tel else False,
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
            "stale": sorted(n for n, v in self.board.agents.items() if v.stale),
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
    context.buses.open()
    context.executor.start()
    node = LanOperator(NodeSettings.from_config(config), context, stale_after=args.stale_after)
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
