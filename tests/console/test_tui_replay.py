"""A recorded flight replayed into the operator console through LCM's ``file://`` provider."""

from __future__ import annotations

from pathlib import Path

from antalate_lcm.core.config import parse_config
from operator_tui.app import OperatorApp
from tests.harness.synthetic_logs import square_swarm


async def test_console_reads_a_log_as_if_live(tmp_path: Path) -> None:
    log = square_swarm().write(tmp_path / "flight.lcm")
    config = parse_config({"agent": {"name": "replay"}, "buses": {"lan": f"file://{log}?speed=0"}})
    app = OperatorApp(config)
    async with app.run_test() as pilot:
        for _ in range(100):
            await pilot.pause(0.1)
            if len(app.board.agents) == 4 and app.board.agents["a-1"].mc_state == "RTL":
                break
        assert sorted(app.board.agents) == ["a-1", "a-2", "a-3", "a-4"]
        assert app.board.agents["a-1"].mc_state == "RTL"
        assert {app.board.agents[a].mc_state for a in ("a-2", "a-3", "a-4")} == {"MISSION"}
