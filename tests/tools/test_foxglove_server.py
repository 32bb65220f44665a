"""``antalate foxglove`` (docs/tools.md): the live swarm over the Foxglove WebSocket protocol, checked by
the protocol's reference client, ``@foxglove/ws-protocol`` from the npm registry, under node."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import jsonschema
import pytest
import tomli_w

from antalate_lcm.cli import main
from antalate_lcm.wire import foxglove_msgs, lcm_json
from tests.conftest import MCAST_URL, Probe
from tests.harness.agents import agent_config
from tests.harness.netns import NetNamespace
from tests.harness.process import stop_process
from tests.tools.npm_tools import node_modules

CLIENT = Path(__file__).parent.parent / "node" / "foxglove_client.mjs"
PORT = 8765  # inside the test's own network namespace: no other server can hold it


def _schema_of(channel: dict[str, Any]) -> dict[str, Any]:
    assert channel["encoding"] == "json" and channel["schemaEncoding"] == "jsonschema"
    schema: dict[str, Any] = json.loads(channel["schema"])
    return schema


@pytest.mark.netns
def test_reference_client_receives_live_positions_with_the_advertised_schemas(
    netns: NetNamespace, probe: Probe, tmp_path: Path
) -> None:
    modules = node_modules()
    agents_cfg = tmp_path / "sim.toml"
    agents_cfg.write_text(tomli_w.dumps(agent_config("sim")))
    viewer_cfg = tmp_path / "viewer.toml"
    viewer_cfg.write_text(f'[agent]\nname = "viewer"\n[buses]\nlan = "{MCAST_URL}"\n')
    agents = netns.antalate(
        "agent", str(agents_cfg), "--agents", "2", stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    server = netns.antalate(
        "foxglove", str(viewer_cfg), "--port", str(PORT), stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    try:
        assert server.stdout is not None
        line = server.stdout.readline()
        assert f"ws://127.0.0.1:{PORT} (read-only)" in line, line
        # hostile or broken senders: garbage on an agent's channel, a fix of NaNs, a foreign channel
        probe.raw("x-9/TELEMETRY", b"\x00garbage")
        probe.publish("x-9/TELEMETRY", "telemetry_t", header={"agent": "x-9"}, lat=float("nan"), lon=1e300)
        probe.raw("NOT/ANTALATE", b"whatever")
        topics = ["sim-01/location", "sim-02/location", "swarm/scene", "sim-01/TELEMETRY", "sim-02/MC_STATE"]
        done = netns.run(
            ["node", str(CLIENT), f"ws://127.0.0.1:{PORT}", "3", "20000", *topics],
            timeout=40,
            env={"PATH": "/usr/bin:/bin", "NODE_PATH": str(modules)},
        )
        assert done.returncode == 0, done.stderr
        report = json.loads(done.stdout)
        assert not report["timedOut"], sorted(report["received"])
        # read-only: the server offers a client no way to publish, call or set anything
        assert report["serverInfo"]["capabilities"] == []
        channels = {c["topic"]: c for c in report["channels"]}
        # the NaN fix is served as it was sent (as "NaN"), but put on no map; nothing else got through
        assert "x-9/TELEMETRY" in channels and "x-9/location" not in channels
        assert "NOT/ANTALATE" not in channels and server.poll() is None
        assert channels["sim-01/location"]["schemaName"] == foxglove_msgs.LOCATION_FIX
        assert channels["swarm/scene"]["schemaName"] == foxglove_msgs.SCENE_UPDATE
        assert channels["sim-01/TELEMETRY"]["schemaName"] == "antalate_lcm.msgs.telemetry_t"
        assert _schema_of(channels["sim-01/TELEMETRY"]) == lcm_json.schema("telemetry_t")
        assert _schema_of(channels["sim-01/location"]) == foxglove_msgs.LOCATION_FIX_SCHEMA
        for topic, messages in report["received"].items():
            schema = _schema_of(channels[topic])
            for message in messages:
                jsonschema.validate(message, schema)
        # the positions are the agents' own: each fix is its TELEMETRY's lat/lon, 8 m apart (--spacing)
        fixes = {t: report["received"][f"{t}/location"][-1] for t in ("sim-01", "sim-02")}
        telemetry = report["received"]["sim-01/TELEMETRY"][-1]
        assert fixes["sim-01"]["frame_id"] == "sim-01"
        assert abs(fixes["sim-01"]["latitude"] - telemetry["lat"]) < 1e-5
        assert abs(fixes["sim-01"]["longitude"] - telemetry["lon"]) < 1e-5
        from antalate_lcm.base.geo import distance

        gap = distance(
            fixes["sim-01"]["latitude"],
            fixes["sim-01"]["longitude"],
            fixes["sim-02"]["latitude"],
            fixes["sim-02"]["longitude"],
        )
        assert 7.0 < gap < 9.0
        assert {e["id"] for m in report["received"]["swarm/scene"] for e in m["entities"]} <= {
            "sim-01",
            "sim-02",
        }
    finally:
        assert stop_process(server) == 0
        stop_process(agents)


def test_beyond_loopback_needs_no_auth(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["foxglove", "--host", "0.0.0.0", "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert "refusing to serve" in err and "--no-auth" in err and "127.0.0.1" in err


def test_without_the_foxglove_extra_it_says_what_to_install() -> None:
    from antalate_lcm.apps.foxglove_server import FOXGLOVE_MISSING
    from tests.architecture.test_optional_extras import antalate_without

    proc = antalate_without("foxglove", "foxglove", "--port", "0")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and err.strip() == f"antalate: {FOXGLOVE_MISSING}"


def test_the_shipped_layout_is_the_generated_one_and_reads_real_fields() -> None:
    """docs/foxglove-layout.json is what tools/foxglove_layout.py writes (foxglove-sdk's layout
    classes), and every topic and field a panel reads is one antalate serves."""
    import re

    from tools.foxglove_layout import AGENT, LAYOUT_FILE, layout_json

    text = LAYOUT_FILE.read_text()
    assert text == layout_json()
    paths = re.findall(r'"(?:value|topicPath|topicToRender)": "([^"]+)"', text)
    assert len(paths) == 6
    for path in paths:
        topic, _, field = path.partition(".")
        if topic == "swarm/log":
            continue
        agent, _, name = topic.partition("/")
        assert agent == AGENT
        props = lcm_json.schema(
            {"TELEMETRY": "telemetry_t", "MC_STATE": "mc_state_t", "HLC_STATE": "hlc_state_t"}[name]
        )
        assert not field or field in props["properties"]
