"""A scripted operator for the headless demo, ``antalate run`` and tests: take off all, fly a
mission (optionally steering it), RTL all.

It talks to the swarm only through the broadcast channels and learns the agents from their
``MC_STATE`` channels, as a human operator would; it records every agent's MC state timeline.
A direction is repeated every second while it holds, as the console does (a direction is a state,
like a stick: ``direction_follow`` hovers after 3 s without one).
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from antalate_lcm.core.node import Context, Node, NodeSettings, TopicMatch
from antalate_lcm.msgs import direction_cmd_t, mc_state_t, operator_cmd_t
from antalate_lcm.wire.vocabulary import Command, McState, member_of

_RESEND = 1.0  # s between repeats of a broadcast command while some agent has not followed


@dataclass(frozen=True)
class DirectionAt:
    """A direction command ``at`` s after the whole swarm entered MISSION (``active`` False: stop)."""

    at: float
    azimuth: float
    speed: float
    active: bool = True


class Phase(enum.Enum):
    WAITING = "waiting for every agent in STANDBY"
    TAKING_OFF = "taking off"
    MISSION = "mission"
    RETURNING = "returning"
    DONE = "done"
    FAILED = "failed"


@dataclass
class Timeline:
    """One agent's MC states with the time (s since the script started) each was first seen."""

    entries: list[tuple[float, McState]] = field(default_factory=list)

    @property
    def current(self) -> McState | None:
        return self.entries[-1][1] if self.entries else None

    def add(self, t: float, state: McState) -> None:
        if self.current is not state:
            self.entries.append((t, state))

    def render(self) -> str:
        return " -> ".join(f"{s.name}@{t:.1f}s" for t, s in self.entries)


class ScriptedOperator(Node):
    """The operator of a headless run: a node of its own (``settings``: the swarm's buses, topics
    and key under the operator's name, `NodeSettings.from_config` with ``agent``), not an agent."""

    kind = "operator"

    def __init__(
        self,
        settings: NodeSettings,
        context: Context,
        *,
        expected_agents: int,
        mission_time: float = 20.0,
        altitude: float = 0.0,
        direction: tuple[float, float] | None = None,
        timeout: float = 180.0,
        directions: Sequence[DirectionAt] = (),
    ) -> None:
        super().__init__(settings, context, watcher=True)  # it watches agents, flies none
        self.expected_agents = expected_agents
        self.mission_time = mission_time
        self.altitude = altitude
        #: (azimuth, speed) from the mission's start, then ``directions`` at their times.
        self.directions = [DirectionAt(0.0, *direction)] if direction is not None else []
        self.directions += sorted(directions, key=lambda d: d.at)
        self.timeout = timeout
        self.timelines: dict[str, Timeline] = {}
        self.phase = Phase.WAITING
        self.reason = ""
        self._t0 = 0.0
        self._phase_at = 0.0
        self._last_sent = -1e9
        self._current: DirectionAt | None = None
        self._direction_sent = -1e9
        #: When the whole swarm entered MISSION (executor clock), None before.
        self.mission_started: float | None = None
        #: Agents the experiment's script crashed or cut off for good: no longer waited for.
        self.excused: set[str] = set()
        #: Called on the executor thread as the script ends (DONE or FAILED), before any node stops.
        self.on_finish: list[Callable[[], None]] = []

    def on_start(self) -> None:
        self._t0 = self._phase_at = self.now
        self.subscribe_all("MC_STATE", self._on_mc_state)
        self.create_timer(0.1, self._step)

    @property
    def finished(self) -> bool:
        return self.phase in (Phase.DONE, Phase.FAILED)

    @property
    def elapsed(self) -> float:
        return self.now - self._t0

    def _on_mc_state(self, msg: mc_state_t, match: TopicMatch) -> None:
        state = member_of(McState, msg.state)
        if state is None:
            return
        agent = match.fields.get("agent", msg.header.agent)
        timeline = self.timelines.get(agent)
        if timeline is None:  # (no Timeline built per message, 5 a second for each agent)
            timeline = self.timelines[agent] = Timeline()
        if timeline.current is not state:  # the time read only for a new state (most repeat it)
            timeline.add(self.elapsed, state)

    def _states(self) -> list[McState | None]:
        return [t.current for a, t in self.timelines.items() if a not in self.excused]

    def _enter(self, phase: Phase) -> None:
        self.log.info("phase: %s (%.1f s)", phase.value, self.elapsed)
        self.phase = phase
        self._phase_at = self.now
        if phase is Phase.MISSION:
            self.mission_started = self.now
        if self.finished:
            for fn in self.on_finish:
                fn()
        self._last_sent = -1e9

    def _broadcast(self, command: Command) -> None:
        if self.now - self._last_sent < _RESEND:
            return
        self._last_sent = self.now
        msg = operator_cmd_t()
        msg.command = int(command)
        msg.altitude = self.altitude
        self._send("SWARM_OPERATOR_CMD", msg)

    def _send(self, topic: str, msg: operator_cmd_t | direction_cmd_t) -> None:
        self.publish(topic, msg)  # signed by Node.publish when a swarm key is configured

    def _step(self) -> None:
        if self.finished:
            return
        if self.elapsed > self.timeout:
            self.reason = f"timed out after {self.timeout:g} s in phase '{self.phase.value}'"
            self._enter(Phase.FAILED)
            return
        # Every agent's state, 10 times a second: asked with the list's own (C) `in` and `count`,
        # equal to `is` here (every entry is an McState member).
        states = self._states()
        if McState.ERROR in states:
            self.reason = "an agent is in ERROR"
            self._enter(Phase.FAILED)
            return
        if self.phase is Phase.WAITING:
            # an agent the script crashed before the take-off is waited for no more
            if len(states) >= self.expected_agents - len(self.excused) and states.count(
                McState.STANDBY
            ) == len(states):
                self._enter(Phase.TAKING_OFF)
        elif self.phase is Phase.TAKING_OFF:
            if states.count(McState.MISSION) == len(states):
                self._enter(Phase.MISSION)
                self._steer()
            elif McState.STANDBY in states:
                self._broadcast(Command.TAKEOFF)
        elif self.phase is Phase.MISSION:
            if self.now - self._phase_at >= self.mission_time:
                self._enter(Phase.RETURNING)
            else:
                self._steer()
        elif self.phase is Phase.RETURNING:
            if states.count(McState.STANDBY) == len(states):
                self._enter(Phase.DONE)
            elif McState.MISSION in states or McState.TAKEOFF in states:
                self._broadcast(Command.RTL)

    def _steer(self) -> None:
        """Send the direction due at this point of the mission: on a change at once, else every second."""
        since = self.now - self._phase_at
        due = None
        for d in self.directions:
            if d.at <= since:
                due = d
        if due is None:
            return
        if due is self._current and self.now - self._direction_sent < _RESEND:
            return
        if due is not self._current:
            self.log.info(
                "direction at %.1f s: %s",
                since,
                f"{due.azimuth:g} deg at {due.speed:g} m/s" if due.active else "stop",
            )
        self._current, self._direction_sent = due, self.now
        msg = direction_cmd_t()
        msg.active, msg.azimuth, msg.speed = due.active, due.azimuth, due.speed
        self._send("SWARM_DIRECTION_CMD", msg)

    def report(self) -> str:
        lines = [
            f"{name}: {tl.render()}" + (" (lost to a fault of the script)" if name in self.excused else "")
            for name, tl in sorted(self.timelines.items())
        ]
        ok = self.phase is Phase.DONE
        lines.append(
            f"{'OK' if ok else 'FAILED'}: {len(self.timelines)} agent(s), "
            f"{'all back in STANDBY' if ok else self.reason} after {self.elapsed:.1f} s"
        )
        return "\n".join(lines)
