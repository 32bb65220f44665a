"""Activation rules of the Behavior Module Arbiter (pure: no I/O, no clock).

Which behaviors run is a function of the state alone (plus whether each is running and whether it
failed), so it is tested here without sockets and the node only carries out the decisions.

Rules, per behavior (docs/design.md §8):

- state ∈ ``activate_on``  → active;
- state ∈ ``deactivate_on`` → inactive;
- any other state: with an empty ``deactivate_on``, inactive; otherwise unchanged (a *hold* state,
  e.g. keep a video recording through RTL after it started in MISSION).

A failed behavior is not re-activated by the periodic republication of the state it failed in:
it is *blocked* until the arbiter receives a state outside its ``activate_on`` (the next activating
state then tries it again) or until the node lifts the block with :meth:`Arbiter.retry` after a
back-off (``[[bma]] restart_backoff``). That keeps a broken behavior from being restarted at 5 Hz,
while one that met a bad input once flies again in the same mission. A behavior that could not
even be constructed is blocked for good.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field


@dataclass(frozen=True)
class ActivationRule:
    activate_on: frozenset[str]
    deactivate_on: frozenset[str] = frozenset()

    @classmethod
    def of(cls, activate_on: Iterable[str], deactivate_on: Iterable[str] = ()) -> ActivationRule:
        return cls(frozenset(activate_on), frozenset(deactivate_on))

    def wants_active(self, state: str, active: bool) -> bool:
        if state in self.activate_on:
            return True
        if not self.deactivate_on or state in self.deactivate_on:
            return False
        return active


@dataclass
class _Standing:
    """A behavior's rule and where it stands with the arbiter (the node's `_Slot` holds the instance)."""

    rule: ActivationRule
    active: bool = False
    failed: str | None = None
    blocked: bool = False
    permanent: bool = False


@dataclass
class Decision:
    """What the node must do for a new state: deactivations first, then activations."""

    deactivate: list[str] = field(default_factory=list)
    activate: list[str] = field(default_factory=list)
    #: Behaviors that stay active through a change of state (they get ``on_state``).
    notify: list[str] = field(default_factory=list)
    state_changed: bool = False
    #: Behaviors whose failure block was lifted by this state (for the log).
    unblocked: list[str] = field(default_factory=list)


class Arbiter:
    """Tracks the state, which behaviors are active, and which failed. The node reports outcomes back."""

    def __init__(self, rules: Mapping[str, ActivationRule]) -> None:
        self._standings: dict[str, _Standing] = {name: _Standing(rule) for name, rule in rules.items()}
        self.state: str = ""
        #: Bumped by every change of the state or of a standing: what the node's status reports is
        #: unchanged while it is (the node then republishes the message it built last).
        self.version = 0
        #: The state whose last `on_state` decided nothing, None once a standing changed since: the
        #: same state again (the MC's periodic republication, 5 a second) would decide nothing again.
        self._settled: str | None = None

    def settled(self, state: str) -> bool:
        """Whether `on_state` would decide nothing for ``state`` (a state message the node may skip)."""
        return state == self._settled and state == self.state

    def on_state(self, state: str) -> Decision:
        decision = Decision(state_changed=state != self.state)
        if decision.state_changed:
            self.version += 1
        self.state = state
        for name, standing in self._standings.items():
            if standing.blocked and not standing.permanent and state not in standing.rule.activate_on:
                standing.blocked = False
                decision.unblocked.append(name)
            want = standing.rule.wants_active(state, standing.active)
            if standing.active and not want:
                decision.deactivate.append(name)
            elif want and not standing.active and not standing.blocked:
                decision.activate.append(name)
            elif standing.active and decision.state_changed:
                decision.notify.append(name)
        quiet = not (
            decision.state_changed
            or decision.deactivate
            or decision.activate
            or decision.notify
            or decision.unblocked
        )
        self._settled = state if quiet else None
        if decision.unblocked:
            self.version += 1
        return decision

    def _changed(self) -> None:
        """A standing changed: the next state message decides afresh, the status is new."""
        self._settled = None
        self.version += 1

    # ------------------------------------------------------------------ outcomes
    def activated(self, name: str) -> None:
        standing = self._standings[name]
        standing.active = True
        standing.failed = None
        self._changed()

    def deactivated(self, name: str) -> None:
        self._standings[name].active = False
        self._changed()

    def failed(self, name: str, reason: str, *, permanent: bool = False) -> None:
        """``name`` raised: it is inactive, reported, and blocked (see the module docstring)."""
        standing = self._standings[name]
        standing.active = False
        standing.failed = reason
        # Only a state that would start it again needs blocking; a failure while leaving (in
        # on_deactivate, or in a hold state) is retried at the next activating state anyway.
        standing.blocked = permanent or self.state in standing.rule.activate_on
        standing.permanent = standing.permanent or permanent
        self._changed()

    def retry(self, name: str) -> bool:
        """Lift a failure block while the state still activates ``name``; True if it should start now."""
        standing = self._standings[name]
        if (
            standing.active
            or standing.permanent
            or not standing.blocked
            or self.state not in standing.rule.activate_on
        ):
            return False
        standing.blocked = False
        self._changed()
        return True

    # ------------------------------------------------------------------ views
    def is_active(self, name: str) -> bool:
        return self._standings[name].active

    def active(self) -> list[str]:
        """Active behaviors in config order (stable, so status messages only change on real changes)."""
        return [name for name, standing in self._standings.items() if standing.active]

    def failures(self) -> dict[str, str]:
        return {
            name: standing.failed for name, standing in self._standings.items() if standing.failed is not None
        }
