"""What the nodes of one process share: the bus connections, the executor, the admission pipeline.

:mod:`antalate_lcm.core.node` re-exports these names (they were defined there before issue #26).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar

from antalate_lcm.base.deprecation import renamed_attribute
from antalate_lcm.base.errors import AntalateError
from antalate_lcm.base.shared import shared_value as shared_value
from antalate_lcm.core.admission import Admission
from antalate_lcm.core.bus import Buses
from antalate_lcm.core.config import Config
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.timers import Ticker

#: The bus name of :meth:`Context.in_process` (memq://, one per process).
INPROC_BUS = "_inproc"
M = TypeVar("M")


def shared_params(params: Callable[..., M], section: Any, *names: str, **renamed: str) -> M:
    """``params(...)`` built from the config ``section``'s fields of the same ``names`` (and of the
    ``renamed`` ones: parameter = field name), one instance per process as :func:`shared_value`.

    Every machine's node (MC, HLC, its velocity guard) turns its config section into the frozen
    parameters its machine reads; this is that copy, written once."""
    values = {name: getattr(section, name) for name in names}
    values.update({param: getattr(section, name) for param, name in renamed.items()})
    return shared_value(params(**values))


@dataclass
class Context:
    """What the nodes of one process share: the bus connections, the executor (its one loop) and the
    admission pipeline (:attr:`admission`: signing, verification, validation, the exposure policy).

    ``inproc_bus`` names a memq:// bus that carries the agents' internal topics between the nodes
    of this process (see :meth:`in_process`); None when each node runs in its own process.
    """

    buses: Buses
    executor: Executor
    inproc_bus: str | None = None
    #: Every agent of the swarm runs in this process (``antalate agent`` without ``--processes``,
    #: the demo): a process-local bus (memq://) then reaches every peer a behavior asks for.
    whole_swarm: bool = False
    #: The run's seed (``antalate run --seed``, and always on simulated time): the agents' timer
    #: phases and the behaviors' random draws (``BehaviorContext.seed``) derive from it, so a run
    #: is a function of it. None: phases fixed by the agents' names, behaviors seed as they like.
    seed: int | None = None
    #: One outgoing message of each type for the nodes of this context that do not sign (`Node.outgoing`): a node
    #: refills it and publish encodes it at once, on the loop's one thread, so a thousand agents'
    #: 20 messages a second touch one object (hot in the cache), not a thousand of their own.
    scratch: dict[type, Any] = field(default_factory=dict, repr=False)
    #: Buses -> their (name, send) pairs, shared by every publisher of the context on those buses.
    senders: dict[tuple[str, ...], list[tuple[str, Callable[[str, bytes], None]]]] = field(
        default_factory=dict, repr=False
    )
    #: Agent name -> the timer its nodes' periodic jobs share (`Node.ticker`): the HLC's and the MC's.
    tickers: dict[str, Ticker] = field(default_factory=dict, repr=False)
    #: The one place this process signs and admits messages (every node's `NodeAdmission` comes from it).
    admission: Admission = field(init=False, repr=False)

    if not TYPE_CHECKING:  # the old name, one release (issue #26's vocabulary); mypy sees only `buses`
        bus = renamed_attribute("buses")

    def __post_init__(self) -> None:
        self.buses.attach(self.executor)  # the bus's descriptors are read on the nodes' loop
        self.admission = Admission(self.buses.urls, simulated=self.executor.sim is not None)

    @classmethod
    def create(cls, config: Config) -> Context:
        return cls(Buses(config.buses), Executor())

    @classmethod
    def in_process(
        cls, buses: Mapping[str, str], *, whole_swarm: bool = False, executor: Executor | None = None
    ) -> Context:
        """A context for every node of one or more agents in this process (``antalate agent``, demo).

        Internal topics (MC_STATE, HLC_STATE, VELOCITY_CMD, ...) are delivered between this
        process's nodes over memq:// and still published on the configured buses for the operator
        and the tools; a spoofed datagram on the LAN never reaches the MC or the HLC.
        ``executor``: the loop to run them on (one on simulated time: ``antalate run --speed``).
        """
        if INPROC_BUS in buses:
            raise AntalateError(f"bus name {INPROC_BUS!r} is reserved for the in-process bus")
        return cls(
            Buses({**buses, INPROC_BUS: "memq://"}),
            executor or Executor(),
            inproc_bus=INPROC_BUS,
            whole_swarm=whole_swarm,
        )

    def close(self) -> None:
        self.executor.stop()
        self.buses.close()
