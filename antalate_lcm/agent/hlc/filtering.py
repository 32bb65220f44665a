"""What the HLC does with the separation and fence filter (docs/safety.md), apart from the node that
polls the vehicle adapter: the swarm picture one process shares, each set-point through the filter, the last
wish re-filtered as peers move, the filtered return leg, the filter's reports and policy, and the fence
mirrored into the autopilot's own.

:class:`SafetyDriver` belongs to one :class:`~antalate_lcm.agent.hlc.node.HlcNode` (built only with
``[safety] enabled``) and acts through it: its adapter calls, its hlc_error_t reports, its sends.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, cast

from antalate_lcm.agent.hlc.machine import ErrorCode, HlcError
from antalate_lcm.agent.hlc.safety import Filtered, SafetyLayer, describe, new_picture
from antalate_lcm.agent.hlc.velocity_guard import Velocity, mission_flight
from antalate_lcm.core.config import Config
from antalate_lcm.core.node import Context, Node, NodeSettings, TopicMatch
from antalate_lcm.msgs import telemetry_t
from antalate_lcm.vehicles import AutopilotError, Frame, VehicleState
from antalate_lcm.wire.vocabulary import HlcState, Severity

if TYPE_CHECKING:
    from antalate_lcm.agent.hlc.node import HlcNode

#: s between two SAFETY hlc_error_t of the same kind (separation, fence, conflict): the console and
#: the log see every episode without a message per set-point.
_SAFETY_REPORT_PERIOD = 1.0
#: s between sweeps of the swarm picture (stale agents out of the grid, silent ones forgotten).
_SWEEP_PERIOD = 0.25
#: HLC states in which the filtered return leg flies (the machine's RTL action started it).
_RETURNING = (HlcState.RTL, HlcState.LOW_BATTERY)


class SharedPicture:
    """The `SwarmPicture` of one process (one `Context`), fed by one hidden node for all its HLCs."""

    def __init__(self, config: Config, context: Context) -> None:
        self.picture = new_picture(config)
        self.feeder = Node(NodeSettings.from_config(config), context, name="safety-picture")
        self.users = 0

    def join(self) -> None:
        self.users += 1
        if self.users > 1:
            return
        feeder, picture = self.feeder, self.picture
        feeder.start()

        def on_telemetry(msg: telemetry_t, m: TopicMatch) -> None:
            picture.feed(m.fields.get("agent", ""), msg, feeder.now)

        feeder.subscribe_all("TELEMETRY", on_telemetry)
        feeder.subscribe_all(
            "MC_STATE", lambda msg, m: picture.state(m.fields.get("agent", ""), msg.state, feeder.now)
        )
        feeder.create_timer(_SWEEP_PERIOD, lambda: picture.sweep(feeder.now))

    def leave(self, context: Context) -> None:
        """One HLC of ``context`` stopped: the last one stops the feeder and forgets the picture."""
        self.users -= 1
        if self.users > 0:
            return
        self.feeder.stop()
        _PICTURES.pop(id(context), None)


#: id(Context) -> its shared picture. A context lives as long as its process's nodes.
_PICTURES: dict[int, SharedPicture] = {}


def shared_picture(config: Config, context: Context) -> SharedPicture:
    shared = _PICTURES.get(id(context))
    if shared is None:
        shared = _PICTURES[id(context)] = SharedPicture(config, context)
    return shared


class SafetyDriver:
    """The filter's side of one HLC: every set-point through it, the return leg, reports, the fence."""

    __slots__ = (
        "node",
        "layer",
        "_wish",
        "_modified",
        "_filtered_at",
        "returning",
        "_landing",
        "_reported",
        "_fence_mirrored",
    )

    def __init__(self, node: HlcNode, layer: SafetyLayer) -> None:
        self.node = node
        self.layer = layer
        self._wish: tuple[Velocity, float] | None = None  # the last velocity a behavior asked for, when
        self._modified = False  # the filter changed the last set-point it saw
        self._filtered_at = -math.inf  # `now` of the last set-point filtered
        self.returning = False  # flying the filtered return leg (RTL with [safety] rtl = "filtered")
        self._landing = False  # the filter's policy asked the vehicle to land
        self._reported: dict[str, float] = {}  # SAFETY report kind -> `now` of the last one
        self._fence_mirrored = False  # the fence was written into the autopilot's own (once per start)

    def wished(self, v: Velocity) -> Velocity:
        """A behavior's set-point ``v``, remembered (re-filtered as peers move) and filtered."""
        self._wish = (v, self.node.now)
        return self.filtered(v)

    def filtered(self, v: Velocity) -> Velocity:
        """`v` through the separation and fence filter (unchanged when it is safe or no fix is known)."""
        node = self.node
        out = self.layer.filter_velocity(node.snapshot, v.vx, v.vy, v.vz, Frame(v.frame), node.now)
        if out is None:
            return v
        self._act_on(out)
        self._modified = out.decision.modified
        self._filtered_at = node.now
        if not out.decision.modified:
            return v
        return Velocity(out.vn, out.ve, out.vd, v.yaw_rate, Frame.NED)

    def taking_off(self, snapshot: VehicleState, now: float) -> None:
        """The HLC enters TAKEOFF: home is here; a crowd around it is reported (the climb keeps it)."""
        layer = self.layer
        layer.mark_home(snapshot)
        self._landing = False
        crowd = layer.crowded(snapshot, now)
        if crowd:
            radius = layer.params.separation.radius
            near = ", ".join(f"{a} at {d:.1f} m" for a, d in crowd)
            text = (
                f"safety: taking off closer than the {radius:g} m radius to {near}: the climb keeps"
                " that distance; the filter separates them only in MISSION"
            )
            self.node.report(HlcError(ErrorCode.SAFETY, Severity.WARNING, text))

    def tick(self, now: float) -> None:
        """Every control tick: the filtered return leg, or the last wish re-filtered as peers move
        (a behavior may command at 1 Hz; the filter must not wait for it)."""
        node = self.node
        if not self._fence_mirrored:
            self._mirror_fence()
        state = node.machine.state
        if self.returning and state not in _RETURNING:
            self.returning = False  # the MC landed it, a pilot took it, ...
        hlc = node.config.hlc
        if node.link_age() >= hlc.link_timeout:
            return
        if self.returning:
            self._return_leg(now)
            return
        if not mission_flight(state, node.mc_state):
            self._wish = None
            return
        if not self._modified and now - self._filtered_at < 2.0 / hlc.control_hz:
            return  # a behavior commanding at 10 Hz or more is filtered on every command already
        wish = self._wish
        fresh = wish is not None and now - wish[1] <= hlc.velocity_timeout
        v = wish[0] if wish is not None and fresh else Velocity.hover()
        was = self._modified
        out = self.filtered(v)
        if self._modified or was:
            node.send_velocity(out)

    def _return_leg(self, now: float) -> None:
        node = self.node
        leg = self.layer.return_leg(node.snapshot, now)
        if leg is None:
            self.returning = False
            if self.layer.home is None or not math.isfinite(node.snapshot.lat):
                node.log.warning("filtered RTL: no home or position known: the autopilot's own RTL")
                node.run_call(node.adapter.rtl, self._after_action)
                return
            node.log.info("filtered RTL: home reached, landing")
            node.run_call(node.adapter.land, self._after_action)
            return
        self._act_on(leg)
        node.send_velocity(Velocity(leg.vn, leg.ve, leg.vd, 0.0, Frame.NED))

    def _act_on(self, f: Filtered) -> None:
        """Report a modified set-point, and follow the filter's policy (land) once."""
        node = self.node
        d = f.decision
        if d.action == "land" and not self._landing:
            self._landing = True
            node.log.warning("%s: landing", describe(d))
            node.run_call(node.adapter.land, self._after_action)
        if not (d.modified or d.reason):
            return
        conflict = bool(d.reason) and not d.reason.startswith("no peer")
        kind = "conflict" if conflict else d.by or "peers"
        now = node.now
        if now - self._reported.get(kind, -math.inf) < _SAFETY_REPORT_PERIOD:
            return
        self._reported[kind] = now
        severity = Severity.ERROR if conflict else Severity.WARNING
        node.report(HlcError(ErrorCode.SAFETY, severity, describe(d)))

    def _mirror_fence(self) -> None:
        """Write the swarm fence into the autopilot's own fence parameters and read them back, once, on
        the ground with a position fix: ArduPilot's FENCE_* (antalate_lcm.vehicles.mavlink.fence_mirror),
        PX4's GF_* (antalate_lcm.vehicles.px4.fence_mirror). It holds if we die."""
        node = self.node
        safety, fence_config = self.layer, node.config.safety.fence
        kind = node.adapter.name
        if fence_config is None or kind not in ("mavlink", "px4") or not node.connected:
            return
        s = node.snapshot
        here = safety.position(s)
        fence = safety.params.fence
        if here is None or fence is None or s.in_air or s.armed:
            return
        self._fence_mirrored = True
        from antalate_lcm.vehicles.mavlink import fence_mirror as ardupilot
        from antalate_lcm.vehicles.px4 import fence_mirror as px4

        module = px4 if kind == "px4" else ardupilot
        wanted = module.fence_parameters(fence, (here[0], here[1]), fence_config.outside)
        link = cast(ardupilot.ParamLink, node.adapter)

        def call() -> None:
            problems = module.mirror(link, wanted)
            if problems:
                raise AutopilotError("; ".join(problems))

        def done(ok: bool, detail: str) -> None:
            if not node.started:
                return
            shown = ", ".join(f"{k} {v:g}" for k, v in wanted.items())
            if ok:
                text = f"safety: fence mirrored into the autopilot and read back: {shown}"
                node.report(HlcError(ErrorCode.SAFETY, Severity.INFO, text))
            else:
                text = f"safety: the autopilot does not hold the fence ({detail}); wanted {shown}"
                node.report(HlcError(ErrorCode.SAFETY, Severity.WARNING, text))

        node.run_call(call, done)

    def _after_action(self, ok: bool, detail: str) -> None:
        if not ok:
            self.node.log.warning("safety: autopilot command failed: %s", detail or "refused")
