"""The antalate operator console: a Textual app that is an LCM node on the LAN bus.

``antalate tui [CONFIG]`` calls :func:`run`. Tests and embedders build :class:`OperatorApp` with a
shared :class:`~antalate_lcm.core.node.Context` instead (e.g. on a ``memq://`` bus).
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Iterator
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from antalate_lcm.core.config import Config
    from operator_tui.app import ConsoleSettings, OperatorApp

__all__ = ["ConsoleSettings", "OperatorApp", "run"]


def __getattr__(name: str) -> object:
    # Lazy: importing the package (e.g. by the CLI's parser) must not pay for importing Textual.
    if name in ("OperatorApp", "ConsoleSettings"):
        from operator_tui import app

        return getattr(app, name)
    raise AttributeError(name)


@contextlib.contextmanager
def _logging_off_the_terminal() -> Iterator[None]:
    """Detach log handlers writing to the terminal while the console draws on it.

    The app shows antalate warnings in its event log instead; handlers are restored on exit.
    """
    root = logging.getLogger()
    streams = (sys.stderr, sys.stdout, sys.__stderr__, sys.__stdout__)
    detached = [
        h
        for h in root.handlers
        if isinstance(h, logging.StreamHandler) and getattr(h, "stream", None) in streams
    ]
    for handler in detached:
        root.removeHandler(handler)
    try:
        yield
    finally:
        for handler in detached:
            root.addHandler(handler)


def run(
    config: Config,
    *,
    name: str = "operator",
    headless_exit_after: float | None = None,
    settings: ConsoleSettings | None = None,
) -> int:
    """Run the console on ``config``'s buses until the operator quits; returns an exit status.

    ``name`` is the console's own agent name (``header.agent`` of its commands): the MC keys
    duplicate detection on it, so two consoles on one swarm should use different names.
    ``headless_exit_after`` runs without a terminal for that many seconds (smoke tests, demos).
    Opens the buses before the UI starts, so a missing multicast route is reported as a plain
    error (:class:`~antalate_lcm.base.errors.MulticastUnavailable`) rather than inside the UI.
    """
    from antalate_lcm.core.node import Context
    from operator_tui.app import OperatorApp

    context = Context.create(config)
    try:
        context.buses.open()
        context.executor.start()
        app = OperatorApp(
            config, context=context, name=name, settings=settings, exit_after=headless_exit_after
        )
        with _logging_off_the_terminal():
            app.run(headless=headless_exit_after is not None)
        return app.return_code or 0
    finally:
        context.close()
