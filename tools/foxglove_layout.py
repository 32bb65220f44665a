"""Write docs/foxglove-layout.json, the Foxglove layout docs/tools.md ships, with foxglove-sdk's own
layout classes (so the file is in the format Foxglove imports): ``python tools/foxglove_layout.py``.

The per-agent panels name the first agent of ``antalate demo`` / ``antalate agent --agents N``
(``sim-01``); docs/tools.md says how to point them at another agent.
"""

from __future__ import annotations

import json
from pathlib import Path

LAYOUT_FILE = Path(__file__).resolve().parent.parent / "docs" / "foxglove-layout.json"
AGENT = "sim-01"


def layout_json() -> str:
    from foxglove import layouts as fl

    def item(
        panel: fl.BasePanel | fl.TabContainer | fl.StackContainer | fl.SplitContainer, proportion: float = 1.0
    ) -> fl.SplitItem:
        return fl.SplitItem(proportion=proportion, content=panel)

    swarm_map = fl.MapPanel(title="Swarm map (every {agent}/location)", config=fl.MapConfig(layer="map"))
    scene = fl.ThreeDeePanel(
        title="Swarm 3D (swarm/scene)",
        config=fl.ThreeDeeConfig(
            follow_tf="swarm", topics={"swarm/scene": fl.BaseRendererSceneUpdateTopicSettings(visible=True)}
        ),
    )
    plot = fl.PlotPanel(
        title=f"{AGENT} altitude and battery",
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(value=f"{AGENT}/TELEMETRY.alt", label="alt (m above home)", enabled=True),
                fl.PlotSeries(value=f"{AGENT}/TELEMETRY.battery", label="battery (%)", enabled=True),
            ]
        ),
    )
    states = fl.StateTransitionsPanel(
        title=f"{AGENT} MC and HLC states",
        config=fl.StateTransitionsConfig(
            paths=[
                fl.StateTransitionsSeries(value=f"{AGENT}/MC_STATE.state", label="MC"),
                fl.StateTransitionsSeries(value=f"{AGENT}/HLC_STATE.state", label="HLC"),
            ]
        ),
    )
    raw = fl.RawMessagesPanel(
        title=f"{AGENT} telemetry", config=fl.RawMessagesConfig(topic_path=f"{AGENT}/TELEMETRY")
    )
    errors = fl.LogPanel(title="HLC errors (swarm/log)", config=fl.LogConfig(topic_to_render="swarm/log"))
    left = fl.SplitContainer(direction="column", items=[item(swarm_map), item(scene)])
    right = fl.SplitContainer(direction="column", items=[item(plot), item(states), item(raw), item(errors)])
    layout = fl.Layout(content=fl.SplitContainer(direction="row", items=[item(left, 2.0), item(right)]))
    return json.dumps(json.loads(layout.to_json()), indent=2, sort_keys=True) + "\n"


if __name__ == "__main__":
    LAYOUT_FILE.write_text(layout_json())
    print(f"wrote {LAYOUT_FILE}")
