"""Finding plugins: by entry point from a separately installed package, and the worked example."""

from __future__ import annotations

import math
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from antalate_lcm.agent.bma import validate_bma_config
from antalate_lcm.base.errors import ConfigError
from antalate_lcm.base.plugins import BEHAVIORS, available
from antalate_lcm.core.config import load_config
from antalate_lcm.msgs import velocity_cmd_t
from tests.harness.bma import harness, make_config
from tests.harness.polling import wait_for

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

HERE = Path(__file__).resolve().parent.parent
PLUGIN_PKG = HERE / "plugin_pkg"
EXAMPLE = HERE.parent / "examples" / "my_behavior"
ECHO_TOPIC = {"ECHO": {"type": "behavior_state_t", "channel": "{agent}/ECHO"}}


def _install_target(pkg: Path, target: Path) -> None:
    """Lay ``pkg`` out as ``pip install --no-deps --target`` does: the package and a ``.dist-info``.

    Done by hand because building a wheel offline needs the ``wheel`` package, which a minimal venv
    lacks; importlib.metadata only looks at the ``.dist-info`` (METADATA + entry_points.txt), and the
    entry points are read from the package's own pyproject.toml, so it stays the single source.
    """
    meta = tomllib.loads((pkg / "pyproject.toml").read_text())
    project = meta["project"]
    for name in meta["tool"]["setuptools"]["packages"]:
        shutil.copytree(pkg / name, target / name)
    dist = target / f"{project['name'].replace('-', '_')}-{project['version']}.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(
        f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n"
    )
    lines: list[str] = []
    for group, entries in project["entry-points"].items():
        lines.append(f"[{group}]")
        lines += [f"{name} = {value}" for name, value in entries.items()]
    (dist / "entry_points.txt").write_text("\n".join(lines) + "\n")
    (dist / "RECORD").write_text("")


@pytest.fixture
def installed_plugin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    _install_target(PLUGIN_PKG, tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    sys.modules.pop("antalate_test_plugin", None)


def _echo_config() -> Any:
    return make_config(
        [{"name": "m", "behaviors": [{"plugin": "test_echo", "params": {"word": "HELLO"}}]}],
        topics=ECHO_TOPIC,
    )


def test_the_test_plugin_is_not_reachable_without_installing_it() -> None:
    assert "test_echo" not in available(BEHAVIORS)
    with pytest.raises(ConfigError, match="no plugin 'test_echo'"):
        validate_bma_config(_echo_config())


def test_a_plugin_from_another_distribution_is_loaded_by_its_entry_point_name(installed_plugin: None) -> None:
    assert "test_echo" in available(BEHAVIORS)
    config = _echo_config()
    validate_bma_config(config)
    with harness(config) as h:
        echoes = h.record("ECHO")
        node = h.bma("m")
        h.mc_state("MISSION")
        assert wait_for(lambda: [m.state for m in echoes] == ["HELLO"])
        assert h.sync(node.active) == ["test_echo"]


def test_the_plugin_params_are_validated_too(installed_plugin: None) -> None:
    config = make_config(
        [{"name": "m", "behaviors": [{"plugin": "test_echo", "params": {"wrod": "x"}}]}], topics=ECHO_TOPIC
    )
    with pytest.raises(ConfigError) as info:
        validate_bma_config(config)
    assert info.value.key == "bma[0].behaviors[0].params.wrod"


# ---------------------------------------------------------------------- the worked example
@pytest.fixture
def example_on_path(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.syspath_prepend(str(EXAMPLE))
    yield
    for name in [m for m in sys.modules if m == "my_behavior" or m.startswith("my_behavior.")]:
        sys.modules.pop(name)


def test_the_example_config_is_valid(example_on_path: None) -> None:
    config = load_config(EXAMPLE / "config.toml")
    validate_bma_config(config)
    assert [b.name for b in config.bma] == ["operator", "mission"]


def test_the_example_behavior_flies_circles_in_mission(example_on_path: None) -> None:
    config = make_config(
        [
            {
                "name": "mission",
                "behaviors": [
                    {
                        "plugin": "my_behavior.circle:Circle",
                        "tick_hz": 50,
                        "params": {"speed": 3.0, "radius": 15.0},
                    }
                ],
            }
        ]
    )
    validate_bma_config(config)
    with harness(config) as h:
        cmds = h.record("VELOCITY_CMD")
        node = h.bma("mission")
        h.mc_state("MISSION")
        assert wait_for(lambda: len(cmds) >= 3)
        cmd = cmds[-1]
        assert cmd.frame == velocity_cmd_t.BODY and cmd.vx == pytest.approx(3.0)
        assert cmd.yaw_rate == pytest.approx(math.degrees(3.0 / 15.0), rel=1e-5)
        h.mc_state("RTL")
        assert wait_for(lambda: cmds[-1].vx == 0.0 and cmds[-1].yaw_rate == 0.0)
        assert h.sync(node.failures) == {}
