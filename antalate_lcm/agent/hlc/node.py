"""The High-Level Control node: wires `HighLevelControl` and `VelocityGuard` to the bus and a vehicle adapter.

A control loop polls the adapter at ``control_hz`` and feeds the machine; the actions it returns are
performed in order, on a worker thread when the adapter's commands may block (see
`VehicleAdapter.blocking`), and their results fed back. Telemetry goes out at ``telemetry_hz``.

An adapter whose ``state()`` raises is a stale link, not a crash: the machine gets the last good
snapshot with its ``link_age`` grown by the time since (so LLC_DOWN follows after ``link_timeout``,
with the exception as the reason, and the recoverable LLC_DOWN row applies once ``state()`` works
again), and the log gets one rate-limited line, not a traceback per tick.

With ``[safety] enabled`` the separation and fence filter is driven by a
:class:`~antalate_lcm.agent.hlc.filtering.SafetyDriver` this node holds: every velocity set-point
passes it, and it runs on each control tick.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from antalate_lcm.agent.hlc.filtering import SafetyDriver, SharedPicture, shared_picture
from antalate_lcm.agent.hlc.machine import (
    NOTHING,
    Action,
    ActionKind,
    ErrorCode,
    HighLevelControl,
    HlcError,
    HlcOutcome,
    HlcParams,
)
from antalate_lcm.agent.hlc.safety import SafetyLayer
from antalate_lcm.agent.hlc.velocity_guard import (
    GuardDecision,
    Velocity,
    VelocityCommand,
    VelocityGuard,
    VelocityLimits,
    Verdict,
    mission_flight,
)
from antalate_lcm.agent.plan import plan_adapter
from antalate_lcm.base.deprecation import renamed_attribute, renamed_names
from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.config import Config
from antalate_lcm.core.node import Context, Node, NodeSettings, shared_params
from antalate_lcm.msgs import hlc_error_t, hlc_state_t, mc_state_t, telemetry_t, velocity_cmd_t
from antalate_lcm.vehicles import AutopilotError, Frame, VehicleAdapter, VehicleState
from antalate_lcm.wire.vocabulary import HlcState, Severity

_CONNECT_RETRY = 2.0  # s between attempts to open the autopilot link
_GAINING_ALTITUDE = HlcState.GAINING_ALTITUDE  # bound once: read on every control tick


def make_adapter(config: Config, context: Context) -> VehicleAdapter:
    """The vehicle adapter ``[hlc] autopilot`` names, on the context's clock (no I/O yet)."""
    return plan_adapter(config).build(context.executor.clock)


class HlcNode(Node):
    kind = "hlc"
    # Slots for the HLC's own attributes: with the node's they were over 30, past which CPython
    # (3.11) gives an instance a dict of its own and every attribute read a hash lookup; the 20 Hz
    # control tick of a thousand agents reads dozens. The base's attributes keep a __dict__.
    __slots__ = (
        "adapter",
        "machine",
        "velocity_guard",
        "mc_state",
        "snapshot",
        "_good",
        "_good_at",
        "_polled_at",
        "_state_fault",
        "_fault_log",
        "connected",
        "_io",
        "_reject_log",
        "_publish_state",
        "_shared",
        "safety",
        "_filter",
        "_clock",
    )

    if not TYPE_CHECKING:  # the old name, one release (issue #26's vocabulary); mypy sees only `adapter`
        autopilot = renamed_attribute("adapter")

    def __init__(self, config: Config, context: Context, adapter: VehicleAdapter | None = None) -> None:
        super().__init__(NodeSettings.from_config(config), context)
        #: The agent's whole config, for this node's own logic (the base node reads only its settings).
        self.config = config
        h = config.hlc
        #: The vehicle adapter the config's ``[hlc] autopilot`` names (or the one given).
        self.adapter = adapter or make_adapter(config, context)
        self.machine = HighLevelControl(
            shared_params(
                HlcParams,
                h,
                "default_takeoff_altitude",
                "airborne_fraction",
                "gain_altitude_timeout",
                "low_battery",
                "link_timeout",
                "low_cell_voltage",
            )
        )
        self.velocity_guard = VelocityGuard(
            shared_params(
                VelocityLimits,
                h,
                "max_yaw_rate",
                "velocity_timeout",
                max_horizontal="max_horizontal_speed",
                max_vertical="max_vertical_speed",
                max_link_age="link_timeout",
            )
        )
        self.mc_state: int | None = None
        self.snapshot = VehicleState()
        self._good = VehicleState()  # the last snapshot state() returned
        self._good_at: float | None = None  # `now` when it did
        self._polled_at: float | None = None  # `now` of `snapshot`
        self._state_fault = ""  # why state() failed on the last tick, "" when it worked
        self._fault_log = RateLimitedLog(self.log, period=30.0)
        self.connected = False
        self._io: ThreadPoolExecutor | None = None
        self._reject_log = RateLimitedLog(self.log, period=5.0)
        self._publish_state: Callable[[], None] = lambda: None
        #: The separation and fence filter (docs/safety.md), None when [safety] is not enabled.
        self._shared: SharedPicture | None = None
        self.safety: SafetyLayer | None = None
        self._filter: SafetyDriver | None = None
        if config.safety.enabled:
            self._shared = shared_picture(config, context)
            self.safety = SafetyLayer(self.agent, config, self._shared.picture)
            self._filter = SafetyDriver(self, self.safety)
        self._clock: Callable[[], float] = context.executor.clock

    @property
    def state(self) -> HlcState:
        return self.machine.state

    # ------------------------------------------------------------------ lifecycle
    def on_start(self) -> None:
        #: The executor's clock, bound once for the 20 Hz control tick (one object for every node;
        #: the adapter's ``state`` is not: a bound method per node is one more object out of the
        #: cache on every tick of a thousand agents, where the adapter is read anyway).
        self._clock = self.context.executor.clock
        if self.adapter.blocking:
            self._io = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"hlc-io-{self.agent}")
        self.subscribe("MC_STATE", self._on_mc_state)
        self.subscribe("VELOCITY_CMD", self._on_velocity)
        if self._shared is not None:
            self._shared.join()
        h = self.config.hlc
        self._telemetry = self.publisher("TELEMETRY")  # its hot path: no topic lookup per message
        self._publish_state = self.state_publisher(
            "HLC_STATE", self._state_msg, h.republish_hz, periodic=False
        )
        # One timer when the rates allow (20, 10 and 5 Hz by default): telemetry and the state go
        # out right after the control tick whose snapshot they report.
        self.ticker(
            h.control_hz,
            [
                (h.control_hz, self._control),
                (h.telemetry_hz, self._publish_telemetry),
                (h.republish_hz, self._publish_state),
            ],
        )
        self._publish_state()
        self._connect()

    def on_stop(self) -> None:
        shared, self._shared = self._shared, None
        if shared is not None:
            shared.leave(self.context)
        io, self._io = self._io, None
        if io is not None:
            io.shutdown(wait=False, cancel_futures=True)
        try:
            self.adapter.close()
        except Exception:
            self.log.exception("closing the %s autopilot failed", self.adapter.name)

    def _connect(self) -> None:
        def done(ok: bool, detail: str) -> None:
            if not self.started:
                return
            if ok:
                self.connected = True
                self.log.info("autopilot %s connected", self.adapter.name)
                return
            self.report(
                HlcError(
                    ErrorCode.LINK_LOST,
                    Severity.ERROR,
                    f"cannot connect the {self.adapter.name} "
                    f"autopilot: {detail}; retrying in {_CONNECT_RETRY:g} s",
                )
            )
            self.call_later(_CONNECT_RETRY, self._connect)

        self.run_call(self.adapter.connect, done)

    # ------------------------------------------------------------------ running adapter calls
    def run_call(self, call: Any, done: Any) -> None:
        """Run ``call()``; then ``done(ok, detail)`` on the executor thread (inline for non-blocking adapters)."""

        def attempt() -> tuple[bool, str]:
            try:
                result = call()
            except AutopilotError as exc:
                return False, str(exc)
            except Exception as exc:  # noqa: BLE001 - an adapter bug must not kill the HLC
                self.log.exception("autopilot %s raised", self.adapter.name)
                return False, f"{type(exc).__name__}: {exc}"
            if result is False:
                # An adapter may say why (ArduCopter's PreArm text): it goes into the hlc_error_t.
                return False, self.adapter.last_refusal or "refused"
            return True, ""

        if self._io is None:
            done(*attempt())
        else:
            post = self.context.executor.call_soon
            self._io.submit(lambda: post(done, *attempt()))

    def _perform(self, action: Action) -> None:
        ap = self.adapter
        calls = {
            ActionKind.ARM: ap.arm,
            ActionKind.DISARM: ap.disarm,
            ActionKind.TAKEOFF: lambda: ap.takeoff(action.altitude),
            ActionKind.LAND: ap.land,
            ActionKind.RTL: ap.rtl,
        }
        self.log.info(
            "autopilot %s%s",
            action.kind.name,
            f" to {action.altitude:g} m" if action.kind is ActionKind.TAKEOFF else "",
        )

        def done(ok: bool, detail: str) -> None:
            if not self.started:
                return
            if not ok:
                self.log.warning("autopilot %s failed: %s", action.kind.name, detail or "refused")
            self._handle(self.machine.on_action_result(action.kind, ok, self.now, detail))

        if (
            action.kind is ActionKind.RTL
            and self._filter is not None
            and self.config.safety.rtl == "filtered"
        ):
            # The HLC flies home itself, through the filter, and lands there (`SafetyDriver.tick`).
            self._filter.returning = True
            self.log.info("RTL: flying home through the safety filter (safety.rtl = filtered)")
            return
        if action.kind is ActionKind.HOVER:
            # Like every velocity set-point, inline: queued behind a slow command on the worker it
            # could arrive after, and override, a newer velocity command.
            self._apply(GuardDecision(Verdict.HOVER, Velocity.hover(), "HLC action"), "HLC")
            return
        self.run_call(calls[action.kind], done)

    # ------------------------------------------------------------------ inputs
    def _on_mc_state(self, msg: mc_state_t) -> None:
        if not self.started:
            return  # delivered after stop(): the adapter is closed
        self.mc_state = msg.state
        alt = (
            msg.takeoff_altitude if math.isfinite(msg.takeoff_altitude) and msg.takeoff_altitude > 0 else 0.0
        )
        outcome = self.machine.on_mc_state(msg.state, self._clock(), takeoff_altitude=alt)
        if outcome is not NOTHING:
            self._handle(outcome)

    def _on_velocity(self, msg: velocity_cmd_t) -> None:
        if not self.started:
            return
        # 10-20 a second per agent in mission flight: one clock read, and nothing built around a
        # command that passes as it came (`VelocityGuard.passes`).
        now = self._clock()
        link_age = self.link_age(now)
        vx, vy, vz, yaw_rate, frame = msg.vx, msg.vy, msg.vz, msg.yaw_rate, msg.frame
        guard, state, mc_state = self.velocity_guard, self.machine.state, self.mc_state
        known = guard.passes(vx, vy, vz, yaw_rate, frame, now, state, mc_state, link_age)
        if known is None:  # rejected, clamped or stale: the guard's decision, logged by _apply
            cmd = VelocityCommand(vx, vy, vz, yaw_rate, frame, now)
            self._apply(guard.on_command(cmd, now, state, mc_state, link_age), msg.header.agent)
        elif self._filter is not None:
            self.send_velocity(self._filter.wished(Velocity(vx, vy, vz, yaw_rate, known)))
        else:
            self._set_velocity(vx, vy, vz, yaw_rate, known)

    def link_age(self, now: float | None = None) -> float:
        """The link's age at ``now`` (default: now): the last snapshot's, plus the time since it was
        taken (20 Hz is coarse)."""
        if self._polled_at is None:
            return math.inf
        return self.snapshot.link_age + max(0.0, (self.now if now is None else now) - self._polled_at)

    def _stale(self, now: float, exc: Exception) -> VehicleState:
        """``state()`` raised ``exc``: the last good snapshot, its link aged by the time since."""
        fault = f"autopilot {self.adapter.name} state() raised {type(exc).__name__}: {exc}"
        if fault != self._state_fault:
            self.log.debug("%s", fault, exc_info=True)
        self._state_fault = fault
        self._fault_log.log(("state",), logging.WARNING, "%s", fault)
        if self._good_at is None:
            return replace(self._good, link_age=math.inf)
        return replace(self._good, link_age=self._good.link_age + max(0.0, now - self._good_at))

    def _control(self) -> None:
        if not self.started:
            return
        now = self._clock()
        # The adapter's snapshot, or the last good one aged by the time since when state() raises.
        try:
            snapshot = self.adapter.state()
        except Exception as exc:  # noqa: BLE001 - an adapter bug is a stale link, not a dead HLC
            snapshot = self._stale(now, exc)
        else:
            if self._state_fault:
                self.log.warning("autopilot %s state() works again", self.adapter.name)
                self._state_fault = ""
            self._good, self._good_at = snapshot, now
        self.snapshot = snapshot
        self._polled_at = now
        machine = self.machine
        # 20 times a second per agent: most outcomes are NOTHING, checked here rather than in a call.
        outcome = machine.on_vehicle(snapshot, now, fault=self._state_fault)
        if outcome is not NOTHING:
            self._handle(outcome)
        if machine.state is _GAINING_ALTITUDE:  # the one state with a timeout (`HighLevelControl.tick`)
            outcome = machine.tick(now)
            if outcome is not NOTHING:
                self._handle(outcome)
        guard = self.velocity_guard
        if guard.last_received is not None:  # else nothing can go stale (`VelocityGuard.tick`)
            # The link's age now is the snapshot's: it was polled at `now` (see _link_age).
            stale = guard.tick(now, machine.state, self.mc_state, self.snapshot.link_age)
            if stale is not None:
                self._apply(stale, "velocity timeout")
        if self._filter is not None:
            self._filter.tick(now)

    # ------------------------------------------------------------------ outputs
    def _apply(self, decision: GuardDecision, source: str) -> None:
        if decision.verdict is Verdict.REJECT:
            # Outside mission flight a velocity command is expected (a behavior's last "stop"),
            # so it is noted; a malformed one in flight is a warning.
            in_mission = mission_flight(self.machine.state, self.mc_state)
            self._reject_log.log(
                ("reject", decision.reason.split(":")[0]),  # per kind: a stale link's age changes every time
                logging.WARNING if in_mission else logging.INFO,
                "rejected velocity command from %s: %s",
                source,
                decision.reason,
            )
            return
        v = decision.send or Velocity.hover()
        if decision.verdict is Verdict.HOVER:
            self.log.info("hover: %s", decision.reason)
        elif decision.clamped:
            self._reject_log.log(("clamp",), logging.INFO, "velocity command clamped: %s", decision.reason)
        if self._filter is not None:
            v = self._filter.wished(v)
        self.send_velocity(v)

    def send_velocity(self, v: Velocity) -> None:
        self._set_velocity(v.vx, v.vy, v.vz, v.yaw_rate, v.frame)

    def _set_velocity(self, vx: float, vy: float, vz: float, yaw_rate: float, frame: Frame | int) -> None:
        """The adapter's `set_velocity`; what it raises is logged (rate-limited), never raised."""
        try:
            if type(frame) is not Frame:  # the guard's set-points carry a Frame already
                frame = Frame(frame)
            self.adapter.set_velocity(vx, vy, vz, yaw_rate, frame)
        except Exception as exc:
            self._reject_log.log(("set_velocity",), logging.WARNING, "set_velocity failed: %s", exc)

    def _handle(self, outcome: HlcOutcome) -> None:
        if outcome is NOTHING:  # most inputs (a snapshot 20 times a second) change nothing
            return
        t = outcome.transition
        if t is not None:
            if t.to_state is HlcState.TAKEOFF and self._filter is not None:
                self._filter.taking_off(self.snapshot, self.now)
            level = logging.INFO
            if t.to_state is HlcState.LLC_DOWN:
                level = logging.ERROR
            elif t.from_state is HlcState.LLC_DOWN or t.to_state is HlcState.HOLD:
                level = logging.WARNING
            self.log.log(
                level, "%s -> %s on %s: %s", t.from_state.name, t.to_state.name, t.event.name, t.reason
            )
            self._publish_state()
        for err in outcome.errors:
            self.report(err)
        for action in outcome.actions:
            self._perform(action)

    def report(self, err: HlcError) -> None:
        level = {Severity.INFO: logging.INFO, Severity.WARNING: logging.WARNING}.get(
            err.severity, logging.ERROR
        )
        self.log.log(level, "error %d (%s): %s", int(err.code), err.code.name, err.text)
        msg = hlc_error_t()
        msg.code = int(err.code)
        msg.severity = int(err.severity)
        msg.text = err.text
        self.publish("HLC_ERROR", msg)

    def _state_msg(self) -> hlc_state_t:
        msg = self.outgoing(hlc_state_t)  # refilled, every field, as the telemetry is
        machine = self.machine
        msg.state = int(machine.state)
        msg.autopilot = self.adapter.name
        msg.reason = machine.reason
        return msg

    def _publish_telemetry(self) -> None:
        s = self.snapshot
        if not s.connected:
            return
        # The context's one telemetry message, refilled (publish stamps its header and encodes it
        # at once): every field of it is written here.
        msg = self.outgoing(telemetry_t)
        msg.lat, msg.lon, msg.alt = s.lat, s.lon, s.alt
        msg.heading, msg.vn, msg.ve, msg.vd = s.heading, s.vn, s.ve, s.vd
        msg.battery, msg.armed, msg.in_air, msg.mode = s.battery, s.armed, s.in_air, s.mode
        self._telemetry.publish(msg)


if not TYPE_CHECKING:  # the old names (base.deprecation.RENAMED_NAMES), unseen by mypy
    __getattr__ = renamed_names(__name__)
