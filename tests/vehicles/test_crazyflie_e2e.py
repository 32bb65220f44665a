"""Whole agents flying emulated Crazyflies: MC + HLC (``autopilot = "crazyflie"``, the real cflib) + BMAs.

One driver process in a private network namespace runs the agents as ``antalate agent`` does
(`agent_nodes` on an in-process context whose ``lan`` bus is real multicast, signed with a swarm key),
the CRTP emulators on 127.0.0.1 (cflib's ``udp://`` driver), and a recorder node that prints every
MC/HLC state change and ``hlc_error_t`` heard on the bus, plus the emulated vehicles' true state, as
JSON lines. The test follows that timeline and injects faults through the driver's stdin.

Covered: a whole mission (take-off to the configured altitude, a direction flown at the right
speed, RTL to the take-off point and landing), low battery by voltage per cell, link loss reported
within ``link_timeout`` + 0.5 s and recovered, a refused arm with its reason in ``hlc_error_t``, and
three Crazyflies as three agents in one process flying ``dovrat_swarm`` the way ``antalate demo``
does. Pilot takeover does not apply: a Crazyflie has no pilot radio in the loop.
"""

from __future__ import annotations

import json
import math
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import MCAST_URL
from tests.harness.netns import NetNamespace
from tests.harness.timeline import EventTimeline

pytest.importorskip("cflib")
pytestmark = pytest.mark.netns

KEY = "crazyflie-e2e-swarm-key"
FAST_AP: dict[str, Any] = {"climb_speed": 1.0, "land_speed": 0.6, "rtl_speed": 1.0, "connect_timeout": 8.0}


def agent_doc(
    name: str,
    tmp_path: Path,
    *,
    operator: dict[str, Any] | None = None,
    mission: str = "direction_follow",
    mission_params: dict[str, Any] | None = None,
    **hlc: Any,
) -> dict[str, Any]:
    bma: list[dict[str, Any]] = []
    if operator is not None:
        bma.append(
            {
                "name": "operator",
                "behaviors": [
                    {
                        "plugin": "auto_operator",
                        "activate_on": ["STANDBY", "MISSION"],
                        "params": {"max_flights": 1, "altitude": 1.0, "retry": 1.0, **operator},
                    }
                ],
            }
        )
    bma.append(
        {
            "name": "mission",
            "behaviors": [{"plugin": mission, "activate_on": ["MISSION"], "params": mission_params or {}}],
        }
    )
    return {
        "agent": {"name": name},
        "buses": {"lan": MCAST_URL},
        "security": {"swarm_key": KEY, "state_dir": str(tmp_path / name)},
        "mc": {"takeoff_ack_timeout": 3.0},
        "hlc": {
            "autopilot": "crazyflie",
            "default_takeoff_altitude": 1.0,
            "gain_altitude_timeout": 8.0,
            "link_timeout": 1.0,
            "max_horizontal_speed": 1.0,
            **hlc,
            "autopilot_params": {**FAST_AP, **hlc.pop("autopilot_params", {})},
        },
        "bma": bma,
    }


@pytest.fixture
def fly(netns: NetNamespace, tmp_path: Path) -> Iterator[Callable[..., EventTimeline]]:
    started: list[EventTimeline] = []

    def start(
        agents: list[tuple[dict[str, Any], dict[str, Any]]], operator: dict[str, Any] | None = None
    ) -> EventTimeline:
        spec = {"agents": [{"doc": doc, "emu": emu} for doc, emu in agents], "operator": operator}
        log_path = tmp_path / f"driver{len(started)}.log"
        with open(log_path, "w") as log:
            proc = netns.python(
                "-m",
                "tests.children.crazyflie_swarm",
                json.dumps(spec),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=log,
            )
        driver = EventTimeline(proc, log_path, noise="emu")
        started.append(driver)
        driver.wait("started", 20)
        return driver

    yield start
    for driver in started:
        driver.stop()


def test_whole_mission_takes_off_flies_the_direction_and_returns_home(
    fly: Callable[..., EventTimeline], tmp_path: Path
) -> None:
    d = fly([(agent_doc("cf1", tmp_path, operator={"rtl_after": 5.0}), {"x": 0.5, "y": -0.5})])
    d.wait("mc", 20, state="MISSION", agent="cf1")
    # AIRBORNE at 95 % of the configured take-off altitude; the high-level commander ends at 1.0 m
    top = d.wait("emu", 5, test=lambda e: abs(e["z"] - 1.0) < 0.02)
    assert top["flying"] and max(e["z"] for e in d.all("emu")) < 1.05  # no overshoot
    # east at 0.4 m/s; the local frame's +x is north (origin_heading 0), so east is -y
    d.send("direction 90 0.4")
    d.wait(
        "emu", 8, test=lambda e: abs(e["vy"] + 0.4) < 0.04 and abs(e["vx"]) < 0.04 and abs(e["z"] - 1.0) < 0.1
    )
    d.wait("mc", 15, state="RTL", agent="cf1")
    d.send("direction 0 0")
    assert d.last("emu")["y"] < -0.5 - 0.5  # it did go east
    d.wait("hlc", 20, state="READY", agent="cf1")
    d.wait("mc", 10, state="STANDBY", agent="cf1")
    home = d.wait("emu", 5, test=lambda e: not e["flying"] and not e["armed"])  # the adapter disarms it
    assert math.hypot(home["x"] - 0.5, home["y"] + 0.5) <= 0.15  # back on the take-off point
    assert home["z"] == 0.0
    assert not [e for e in d.errors() if e["code"] not in ("LINK_REGAINED",)], d.timeline()


def test_low_battery_per_cell_returns_home_and_lands(
    fly: Callable[..., EventTimeline], tmp_path: Path
) -> None:
    # low_battery 5%: the firmware's 10% at 3.4 V is above it, so the voltage per cell is what fires
    d = fly([(agent_doc("cf1", tmp_path, operator={}, low_battery=5.0), {})])
    d.wait("mc", 20, state="MISSION", agent="cf1")
    d.send("battery 0 3.4")  # 1S: 3.4 V per cell <= low_cell_voltage 3.5
    d.wait("hlc", 5, state="LOW_BATTERY", agent="cf1")
    error = d.wait("error", 5, code="LOW_BATTERY")
    assert "per cell" in error["text"] and "3.4" in error["text"]
    d.wait("mc", 5, state="RTL", agent="cf1")
    d.wait("hlc", 20, state="READY", agent="cf1")
    landed = d.wait("emu", 5, test=lambda e: not e["flying"] and not e["armed"])
    assert math.hypot(landed["x"], landed["y"]) <= 0.15


def test_link_loss_is_reported_within_link_timeout_and_recovered(
    fly: Callable[..., EventTimeline], tmp_path: Path
) -> None:
    d = fly([(agent_doc("cf1", tmp_path, operator={}), {})])
    d.wait("mc", 20, state="MISSION", agent="cf1")
    d.send("silent 0 1")
    silenced = d.wait("silent", 5, on=True)
    down = d.wait("hlc", 5, state="LLC_DOWN", agent="cf1")
    assert down["t"] - silenced["t"] <= 1.0 + 0.5  # link_timeout + 0.5 s
    d.wait("error", 2, code="LINK_LOST")
    d.wait("mc", 5, state="ERROR", agent="cf1")
    flying = d.last("emu")
    assert flying["flying"] and flying["z"] > 0.8  # the high-level commander holds it
    d.send("silent 0 0")
    d.wait("error", 5, code="LINK_REGAINED")
    d.wait("mc", 10, state="RTL", agent="cf1")  # [mc] on_link_regained = rtl
    d.wait("hlc", 20, state="READY", agent="cf1")
    d.wait("mc", 10, state="STANDBY", agent="cf1")


@pytest.mark.parametrize(
    ("emu", "words"),
    [
        ({"locked": True}, ("locked", "reboot")),
        ({"converged": False}, ("not converged", "max_position_variance")),
    ],
    ids=["locked-supervisor", "estimator-not-converged"],
)
def test_refused_arm_reaches_the_operator_with_its_reason(
    fly: Callable[..., EventTimeline], tmp_path: Path, emu: dict[str, Any], words: tuple[str, ...]
) -> None:
    d = fly([(agent_doc("cf1", tmp_path, operator={}), emu)])
    error = d.wait("error", 20, code="ARM_FAILED")
    assert all(w in error["text"] for w in words), error
    d.wait("mc", 10, state="STANDBY", agent="cf1")
    assert not d.last("emu")["flying"]


def test_three_crazyflies_in_one_process_fly_dovrat_swarm(
    fly: Callable[..., EventTimeline], tmp_path: Path
) -> None:
    agents = [
        (
            agent_doc(
                f"cf{i + 1}",
                tmp_path,
                mission="dovrat_swarm",
                mission_params={"forward_speed": 0.3, "sharp_turn_rate": 20.0},
            ),
            {"x": 0.0, "y": 1.5 * i},
        )
        for i in range(3)
    ]
    d = fly(agents, operator={"mission_time": 4.0})
    done = d.wait("operator", 90)
    assert done["phase"] == "DONE", done["report"] + "\n" + d.timeline()
    mark = d.mark()
    for i in range(3):
        name = f"cf{i + 1}"
        assert d.last("mc", agent=name)["state"] == "STANDBY"  # heard before the operator's DONE
        d.rewind(mark)  # the three land in any order: each is looked for from the operator's DONE
        final = d.wait("emu", 5, agent=name, test=lambda e: not e["flying"] and not e["armed"])
        assert math.hypot(final["x"], final["y"] - 1.5 * i) <= 0.15  # each back on its own take-off point
