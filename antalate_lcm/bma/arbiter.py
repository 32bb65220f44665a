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
class _Slot:
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
        self._slots: dict[str, _Slot] = {name: _Slot(rule) for name, rule in rules.items()}
        self.state: str = ""

    def on_state(self, state: str) -> Decision:
        decision = Decision(state_changed=state != self.state)
        self.state = state
        for name, slot in self._slots.items():
            if slot.blocked and not slot.permanent and state not in slot.rule.activate_on:
                slot.blocked = False
                decision.unblocked.append(name)
            want = slot.rule.wants_active(state, slot.active)
            if slot.active and not want:
                decision.deactivate.append(name)
            elif want and not slot.active and not slot.blocked:
                decision.activate.append(name)
            elif slot.active and decision.state_changed:
                decision.notify.append(name)
        return decision

    # ------------------------------------------------------------------ outcomes
    def activated(self, name: str) -> None:
        slot = self._slots[name]
        slot.active = True
        slot.failed = None

    def deactivated(self, name: str) -> None:
        self._slots[name].active = False

    def failed(self, name: str, reason: str, *, permanent: bool = False) -> None:
        """``name`` raised: it is inactive, reported, and blocked (see the module docstring)."""
        slot = self._slots[name]
        slot.active = False
        slot.failed = reason
        # Only a state that would start it again needs blocking; a failure while leaving (in
        # on_deactivate, or in a hold state) is retried at the next activating state anyway.
        slot.blocked = permanent or self.state in slot.rule.activate_on
        slot.permanent = slot.permanent or permanent

    def retry(self, name: str) -> bool:
        """Lift a failure block while the state still activates ``name``; True if it should start now."""
        slot = self._slots[name]
        if slot.active or slot.permanent or not slot.blocked or self.state not in slot.rule.activate_on:
            return False
        slot.blocked = False
        return True

    # ------------------------------------------------------------------ views
    def is_active(self, name: str) -> bool:
        return self._slots[name].active

    def active(self) -> list[str]:
        """Active behaviors in config order (stable, so status messages only change on real changes)."""
        return [name for name, slot in self._slots.items() if slot.active]

    def failures(self) -> dict[str, str]:
        return {name: slot.failed for name, slot in self._slots.items() if slot.failed is not None}
