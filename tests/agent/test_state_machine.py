"""The state-machine engine (antalate_lcm/base/state_machine.py) the MC and HLC tables run on: rows read top to
bottom, guards that fall through, and guards that cannot write to the machine they read."""

from __future__ import annotations

import enum
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from antalate_lcm.base.state_machine import Row, Table
from tests import REPO


class S(enum.Enum):
    A = "A"
    B = "B"
    C = "C"


class E(enum.Enum):
    GO = "GO"
    STOP = "STOP"


class View(Protocol):
    @property
    def ready(self) -> bool: ...


@dataclass
class Machine:
    ready: bool = False


def _ready(m: View) -> bool:
    return m.ready


ROWS = (
    Row[S, E, View](frozenset({S.A}), E.GO, S.C, "ready: straight to C", guard=_ready),
    Row[S, E, View](frozenset({S.A, S.B}), E.GO, S.B, "not ready: B"),
    Row[S, E, View](frozenset({S.B}), E.STOP, None, "stay"),
)
TABLE: Table[S, E, View, Row[S, E, View]] = Table(ROWS)


def test_the_first_row_whose_guard_holds_wins_in_table_order() -> None:
    assert TABLE.match(S.A, E.GO, Machine(ready=True)) is ROWS[0]
    assert TABLE.match(S.A, E.GO, Machine(ready=False)) is ROWS[1]  # the guard fails: the next row
    assert TABLE.match(S.B, E.GO, Machine(ready=True)) is ROWS[1]  # the guarded row is not B's
    assert TABLE.match(S.C, E.GO, Machine(ready=True)) is None  # no row of C
    assert TABLE.match(S.A, E.STOP, Machine()) is None  # a row of B only


def test_what_a_state_takes_and_where_an_event_is_taken() -> None:
    assert TABLE.events_taken(S.A) == {E.GO}
    assert TABLE.events_taken(S.B) == {E.GO, E.STOP}
    assert TABLE.events_taken(S.C) == frozenset()
    assert TABLE.sources_of(E.GO) == {S.A, S.B}
    assert list(TABLE) == list(ROWS)


def test_a_guard_cannot_write_to_the_machine_it_reads(tmp_path: Path) -> None:
    """The views are read-only for mypy --strict: a guard that assigns to one is a type error (the MC's
    and HLC's guards used to take the machine itself, and one wrote its private takeoff altitude)."""
    source = tmp_path / "bad_guard.py"
    source.write_text(
        textwrap.dedent(
            """
            from antalate_lcm.agent.hlc.machine import HlcView
            from antalate_lcm.agent.mc.machine import McView

            def mc_guard(m: McView) -> bool:
                m.hlc_changed = True
                return True

            def hlc_guard(m: HlcView) -> bool:
                m.target_altitude = 5.0
                return True
            """
        )
    )
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--strict", "--cache-dir", str(tmp_path / "cache"), str(source)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert proc.stdout.count("is read-only") == 2, proc.stdout
