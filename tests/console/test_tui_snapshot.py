"""A snapshot of the console's main screen, as text, against ``tests/snapshots/tui_main_screen.txt``.

Text rather than SVG so a change shows up as a readable diff in review. It is deterministic by
construction, not by masking: the clocks are fake (link ages, command ages and the event log's
times are fixed), the log's times are formatted in UTC, and every message is drained before time
moves. Colours are covered by the state-colour assertions in test_tui.py and test_tui_model.py.

After an intended UI change: ``ANTALATE_UPDATE_SNAPSHOTS=1 pytest tests/console/test_tui_snapshot.py``,
then review the diff of the .txt file.
"""

from __future__ import annotations

import html
import os
import re
from pathlib import Path

from antalate_lcm.core.node import Context
from antalate_lcm.msgs import hlc_error_t, hlc_state_t, mc_state_t
from operator_tui.app import OperatorApp
from operator_tui.commands import Status
from tests.console import test_tui
from tests.console.test_tui import FakeSwarm, make_app, until, wait_dirs, wait_sent
from tests.harness.clock import FakeClock

# The pilot tests' fixtures (a memq bus shared with fake agents, a fake clock), reused as they are.
context = test_tui.context
swarm = test_tui.swarm
clock = test_tui.clock

SNAPSHOT = Path(__file__).parent.parent / "snapshots" / "tui_main_screen.txt"
SIZE = (150, 42)


#: One drawn run of text in the SVG that App.export_screenshot returns (rich's export_svg): its x (px),
#: the width it is drawn in (px, ``len(text)`` cells), its screen line (in the clip path) and the text.
_RUN = re.compile(
    r'<text [^>]*?x="([\d.]+)" [^>]*?textLength="([\d.]+)" clip-path="url\(#[\w-]+-line-(\d+)\)">([^<]*)</text>'
)


def screen_text(app: OperatorApp) -> str:
    """The screen as plain text, read back from Textual's public SVG screenshot.

    Each run of text carries its position; blanks are not drawn, so they are filled back in by column.
    """
    width, height = app.size
    rows = [[" "] * width for _ in range(height)]
    for x, length, line, raw in _RUN.findall(app.export_screenshot()):
        text = html.unescape(raw).replace("\xa0", " ")
        column = round(float(x) * len(text) / float(length))
        rows[int(line)][column : column + len(text)] = text
    return "\n".join("".join(row).rstrip() for row in rows) + "\n"


async def test_main_screen_snapshot(context: Context, swarm: FakeSwarm, clock: FakeClock) -> None:
    app = make_app(context, clock)
    async with app.run_test(size=SIZE) as pilot:
        swarm.agent("alpha", lat=47.39770, lon=8.54560)
        swarm.flying("bravo", lat=47.39810, lon=8.54640, alt=15.2, heading=45.0, vn=1.4, ve=1.4, battery=76.0)
        swarm.arbiter("bravo", "main", "MISSION", ["dovrat_swarm", "video_capture"])
        swarm.agent(
            "charlie",
            mc=mc_state_t.RTL,
            hlc=hlc_state_t.LOW_BATTERY,
            lat=47.39740,
            lon=8.54700,
            alt=22.0,
            heading=200.0,
            vn=-2.0,
            ve=-0.7,
            battery=18.0,
            in_air=True,
        )
        swarm.error("charlie", "battery 18% <= 20%: returning home", code=21, severity=hlc_error_t.WARNING)
        swarm.agent(
            "delta", mc=mc_state_t.ERROR, hlc=hlc_state_t.LLC_DOWN, lat=47.39700, lon=8.54520, battery=-1.0
        )
        swarm.error("delta", "no autopilot heartbeat for 3.0 s", code=2, severity=hlc_error_t.CRITICAL)
        swarm.agent("echo", lat=47.39790, lon=8.54480, heading=300.0)
        await until(pilot, app, lambda: len(app.board.agents) == 5 and app.board.agents["delta"].last_error)

        # TAKEOFF alpha, acknowledged 0.4 s later.
        await pilot.press("home", "t")
        ((_, takeoff),) = await wait_sent(pilot, app, swarm, 1)
        clock.advance(0.4)
        swarm.mc("alpha", mc_state_t.TAKEOFF, last=takeoff.header.seq)
        await until(pilot, app, lambda: app.tracker.counts()[Status.ACKED] == 1)
        # LAND bravo (pending, no ack yet) and steer bravo north-east.
        await pilot.press("down", "l", "d", "d", "d", "w")
        await wait_sent(pilot, app, swarm, 2)
        await wait_dirs(pilot, app, swarm, 4)

        # Four seconds on: everybody but echo keeps publishing, so echo goes stale.
        clock.advance(0.5)
        for name in ("alpha", "bravo", "charlie", "delta"):
            state = app.board.agents[name].mc_state
            assert state, f"{name} has no MC state yet"
            swarm.mc(name, mc_state_t.__dict__[state], last=takeoff.header.seq if name == "alpha" else 0)
        await until(
            pilot, app, lambda: all(app.board.agents[n].last_heard == clock() for n in ("alpha", "delta"))
        )
        clock.advance(3.0)
        swarm.mc("bravo", mc_state_t.MISSION)
        await until(
            pilot,
            app,
            lambda: app.board.agents["echo"].stale and app.board.agents["bravo"].last_heard == clock(),
        )
        app.refresh_now()
        await pilot.pause()
        text = screen_text(app)

    if os.environ.get("ANTALATE_UPDATE_SNAPSHOTS") or not SNAPSHOT.exists():
        SNAPSHOT.parent.mkdir(exist_ok=True)
        SNAPSHOT.write_text(text, encoding="utf-8")
    assert text == SNAPSHOT.read_text(encoding="utf-8"), (
        f"the main screen changed; if intended, rerun with ANTALATE_UPDATE_SNAPSHOTS=1 and review {SNAPSHOT}"
    )
