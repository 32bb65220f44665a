"""Modal screens: the confirmation asked before any all-agent command, and the help page.

Command keys are bound on the main screen, not the app, so while a modal is open a stray ``t``
cannot launch anything: only the modal's own keys work.
"""

from __future__ import annotations

from typing import ClassVar

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Button, Static


class ConfirmScreen(ModalScreen[bool]):
    """Ask before a command goes to every agent; y/enter confirms, n/escape cancels."""

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("y", "answer(True)", "Yes"),
        Binding("n", "answer(False)", "No"),
        Binding("escape", "answer(False)", "Cancel", show=False),
    ]

    def __init__(self, question: str, detail: str = "") -> None:
        super().__init__()
        self.question = question
        self.detail = detail

    def compose(self) -> ComposeResult:
        with Vertical(id="confirm-box"):
            yield Static(Text(self.question, "bold"), id="confirm-question")
            if self.detail:
                yield Static(self.detail, id="confirm-detail")
            with Horizontal(id="confirm-buttons"):
                yield Button("Yes (y)", variant="error", id="yes")
                yield Button("No (n)", variant="primary", id="no")

    def on_mount(self) -> None:
        # Focus "No": an absent-minded enter must not send a command to the whole swarm.
        self.query_one("#no", Button).focus()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        event.stop()
        self.dismiss(event.button.id == "yes")

    def action_answer(self, answer: bool) -> None:
        self.dismiss(answer)


HELP = """\
[b]antalate operator console[/b]

[b]Select[/b]    ↑ ↓ PgUp PgDn Home End   move the selection in the agent table
[b]Commands[/b]  t / T   TAKEOFF the selected agent / ALL agents (asks first)
          l / L   LAND    the selected agent / ALL agents (asks first)
          r / R   RTL     the selected agent / ALL agents (asks first)
[b]Direction[/b] a d ← →  rotate the azimuth by ∓15°     w s   speed ±0.5 m/s
          space   stop (direction inactive)         D     target: selected agent ⇄ ALL (asks first)
[b]Other[/b]     ?       this help                         q     quit

[b]Pending / acknowledged / failed[/b]
Each TAKEOFF/LAND/RTL gets its own sequence number. It stays [yellow]pending[/yellow] until the agent's
MC reports that number as its [i]last_command_seq[/i] ([green]acked[/green]); meanwhile it is resent
every second with the same number (the MC ignores duplicates). With no acknowledgement after the
timeout it is [red]failed[/red] — lost, or rejected because it does not apply in the MC's state
(e.g. LAND on the ground). A command to ALL waits for every agent that was live when it was sent.
Directions have no acknowledgement; the latest one is repeated every second.

[b]Table[/b]  Link = time since the agent was last heard ("ok" under 1 s); an agent silent for
longer than the stale timeout is shown [dim]dim[/dim] with a [red]red[/red] age and stays listed.
Map: north up, arrows point along headings, a digit counts agents sharing a cell, × = stale.

Press escape, ? or q to close.
"""


class HelpScreen(ModalScreen[None]):
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("escape", "close", "Close"),
        Binding("question_mark", "close", "Close", show=False),
        Binding("q", "close", "Close", show=False),
    ]

    def compose(self) -> ComposeResult:
        with VerticalScroll(id="help-box"):
            yield Static(HELP, id="help-text")

    def action_close(self) -> None:
        self.dismiss(None)
