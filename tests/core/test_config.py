"""Config loading: every invalid file stops with the file, the key and what was expected."""

from __future__ import annotations

from pathlib import Path

import pytest

from antalate_lcm.agent.plan import load_plan
from antalate_lcm.base.errors import AntalateError, ConfigError
from antalate_lcm.core.config import Config, TopicsConfig, check_unique_agent_names, load_config, parse_config
from tests import REPO
from tests.harness.cases import cases


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "agent.toml"
    p.write_text(text)
    return p


def test_defaults_are_one_simulated_agent_with_an_anonymous_name() -> None:
    a, b = load_config(None), load_config(None)
    assert a.hlc.autopilot == "sim"
    assert a.agent.name.startswith("anon-") and a.agent.name != b.agent.name
    assert a.topic_buses("MC_STATE") == ["lan"]


def test_full_file(tmp_path: Path) -> None:
    cfg = load_config(
        write(
            tmp_path,
            """
[agent]
name = "alpha"
[buses]
lan = "udpm://239.255.76.67:7667?ttl=1"
local = "udpm://239.255.76.67:7668?ttl=0"
[topics]
default_bus = "local"
MC_STATE = ["local", "lan"]
OPERATOR_CMD = "lan"
VELOCITY_CMD = { bus = "local", channel = "{agent}/VEL" }
SWARM_MODE = { type = "behavior_state_t", channel = "{agent}/SWARM_MODE" }
[hlc]
autopilot = "sim"
[hlc.autopilot_params]
home_lat = 32.1
""",
        )
    )
    assert cfg.agent.name == "alpha"
    assert cfg.topic_buses("MC_STATE") == ["local", "lan"]
    assert cfg.topic_buses("TELEMETRY") == ["local"]
    specs = cfg.topic_specs()
    assert specs["VELOCITY_CMD"].channel == "{agent}/VEL"
    assert specs["SWARM_MODE"].msg_type.__name__ == "behavior_state_t"
    assert cfg.hlc.autopilot_params == {"home_lat": 32.1}


def test_the_bus_a_tool_watches_and_an_undeclared_one_refused() -> None:
    """``antalate log``, ``run``'s recording and the Foxglove bridge open ``--bus``, else ``lan``, else
    the default bus; a name the file does not declare is refused naming the declared ones."""
    two = Config(buses={"lan": "memq://", "local": "memq://"}, topics=TopicsConfig(default_bus="local"))
    assert (two.watched_bus(None), two.watched_bus("local")) == ("lan", "local")
    no_lan = Config(buses={"local": "memq://"}, topics=TopicsConfig(default_bus="local"))
    assert no_lan.watched_bus(None) == "local"
    assert two.bus_url("local") == "memq://"
    with pytest.raises(AntalateError, match=r"^no bus named 'wan' in <defaults>; declared: lan, local$"):
        two.bus_url("wan")


def test_design_style_autopilot_table(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, '[hlc.autopilot]\nname = "tello"\nhost = "192.168.10.1"\n'))
    assert cfg.hlc.autopilot == "tello"
    assert cfg.hlc.autopilot_params == {"host": "192.168.10.1"}


@pytest.mark.parametrize(
    "text",
    [
        '[hlc.autopilot]\nname = "sim"\ntau = 0.4\n',  # the design draft's table, name inside
        '[hlc]\nautopilot = { name = "sim", tau = 0.4 }\n',  # the same, inline
        '[hlc]\nadapter = "sim"\n[hlc.autopilot]\ntau = 0.4\n',  # the name beside the table
        "[hlc.autopilot]\ntau = 0.4\n",  # no name: the sim
    ],
)
def test_deprecated_autopilot_spellings_load_the_same_plan_with_a_warning(tmp_path: Path, text: str) -> None:
    canonical = load_plan(write(tmp_path, '[hlc]\nautopilot = "sim"\n[hlc.autopilot_params]\ntau = 0.4\n'))
    path = write(tmp_path, text)
    with pytest.warns(
        FutureWarning, match=r"\[hlc.autopilot\] table is deprecated.*autopilot = \"sim\""
    ) as seen:
        plan = load_plan(path)
    assert str(path) in str(seen[0].message)
    assert (plan.adapter.name, plan.adapter.cls, dict(plan.adapter.params)) == (
        "sim",
        canonical.adapter.cls,
        {"tau": 0.4},
    )
    assert plan.adapter.model == canonical.adapter.model


def test_the_canonical_autopilot_spelling_warns_nothing(tmp_path: Path) -> None:
    import warnings

    path = write(tmp_path, '[hlc]\nautopilot = "sim"\n[hlc.autopilot_params]\ntau = 0.4\n')
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plan = load_plan(path)
    assert plan.adapter.build(lambda: 0.0).params == {"tau": 0.4}


def test_a_bad_adapter_name_beside_the_table_names_hlc_adapter(tmp_path: Path) -> None:
    err = assert_config_error(
        write(tmp_path, '[hlc]\nadapter = "simm"\n[hlc.autopilot]\ntau = 0.4\n'), "hlc.adapter", "'simm'"
    )
    _installed_listed(err.expected)


def test_a_config_loads_without_importing_its_plugins(tmp_path: Path) -> None:
    """The config is data: plugins are resolved once, by the plan (`antalate_lcm.agent.plan`)."""
    path = write(tmp_path, '[hlc]\nautopilot = "nope"\n')
    assert load_config(path).hlc.autopilot == "nope"
    assert_config_error(path, "hlc.autopilot", "there is no adapter 'nope'")


@pytest.mark.parametrize(("text", "key", "expected"), cases("core/bad_configs.toml"))
def test_invalid_files_name_file_key_and_expectation(
    tmp_path: Path, text: str, key: str, expected: str
) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    err = info.value
    assert err.file == str(path)
    assert err.key == key
    assert expected in err.expected
    assert str(path) in str(err) and key in str(err)


def test_not_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[agent\nname=1"))


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="file not found"):
        load_config(tmp_path / "nope.toml")


def test_cli_reports_a_bad_config_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from antalate_lcm.cli import main

    path = write(tmp_path, "[hlc]\nlow_battery = 150\n")
    assert main(["spy", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hlc.low_battery" in err[0] and str(path) in err[0]


def test_parse_config_keeps_a_given_name() -> None:
    assert parse_config({"agent": {"name": "bravo"}}).agent.name == "bravo"


@pytest.mark.parametrize("example", sorted((REPO / "examples").glob("*.toml")), ids=lambda p: p.name)
def test_examples_are_valid(example: Path) -> None:
    from antalate_lcm.runtime.agent import validate

    validate(load_config(example))  # plugins and their params too


# ------------------------------------------------------------------ strict: no silent coercion

BEHAVIOR = "[[bma]]\nname = 'a'\n[[bma.behaviors]]\nplugin = 'auto_operator'\n"
DOVRAT = "[[bma]]\nname = 'a'\n[[bma.behaviors]]\nplugin = 'dovrat_swarm'\nactivate_on = ['MISSION']\n"


def assert_config_error(path: Path, key: str, *expected: str) -> ConfigError:
    """``path`` fails to load with one line naming the file, ``key`` and each ``expected`` phrase.

    Loaded as every command does: the config, then its plugins and their params (`load_plan`)."""
    with pytest.raises(ConfigError) as info:
        load_plan(path)
    err = info.value
    assert (err.file, err.key) == (str(path), key), str(err)
    for phrase in expected:
        assert phrase in err.expected, str(err)
    text = str(err)
    assert "\n" not in text and text.startswith(f"invalid config {path}: {key}: "), text
    return err


@pytest.mark.parametrize(("text", "key", "expected"), cases("core/no_coercion.toml"))
def test_no_silent_coercion_in_any_section(tmp_path: Path, text: str, key: str, expected: str) -> None:
    assert_config_error(write(tmp_path, text), key, expected)


def test_an_integer_still_fills_a_float(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, "[hlc]\ntelemetry_hz = 5\n[osc]\nrate = 1\n[security]\nwindow = 3\n"))
    assert cfg.hlc.telemetry_hz == 5.0 and isinstance(cfg.hlc.telemetry_hz, float)
    assert cfg.osc.rate == 1.0 and cfg.security.window == 3.0


# ------------------------------------------------------------------ bus URLs (LCM's providers)


@pytest.mark.parametrize(
    "url",
    [
        "udpm://",  # liblcm's default group and port
        "udpm://239.255.76.67:7667",
        "udpm://239.255.76.67:7667?ttl=0",
        "udpm://224.0.0.251:1?ttl=255&recv_buf_size=2097152",
        "udpm://239.255.76.67:7667?ttl=1?recv_buf_size=1048576",  # liblcm also splits at every '?'
        "memq://",
        "file:///tmp/flight.lcm",
        "file://logs/flight.lcm?mode=w",
        "file:///tmp/flight.lcm?mode=r&speed=0&start_timestamp=1700000000000000",
        "file:///tmp/flight.lcm?mode=a",
        "file:///tmp/flight.lcm?speed=-1.5",
        "mpudpm://239.255.76.67:7667?nports=16&ttl=1",
        "tcpq://",
        "tcpq://127.0.0.1:7700",
        "tcpq://lcm-server.local:7700",
    ],
)
def test_every_lcm_provider_is_accepted(tmp_path: Path, url: str) -> None:
    assert load_config(write(tmp_path, f'[buses]\nlan = "{url}"\n')).buses["lan"] == url


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        (
            "http://127.0.0.1:8080",
            "an LCM provider (udpm://, mpudpm://, memq://, file://, tcpq://, zenoh://), not 'http://'",
        ),
        ("udp://239.255.76.67:7667", "not 'udp://'"),
        ("localhost:7667", "provider://network"),
        ("://239.255.76.67:7667", "provider://network"),
        ("udpm://239.255.76.67:99999", "a port 1-65535 after the group, not '99999'"),
        ("udpm://239.255.76.67:0", "a port 1-65535"),
        ("udpm://239.255.76.67:76x7", "a port 1-65535"),
        ("udpm://239.255.76.67", "a port after the group"),
        ("udpm://239.255.76:7667", "dotted IPv4 multicast group"),
        ("udpm://239.255.76.300:7667", "dotted IPv4 multicast group"),
        ("udpm://lcm.local:7667", "dotted IPv4 multicast group"),
        ("udpm://:7667", "dotted IPv4 multicast group"),
        ("udpm://192.168.1.20:7667", "multicast group (224.0.0.0/4); 192.168.1.20 is a unicast address"),
        ("udpm://240.0.0.1:7667", "unicast"),
        ("udpm://239.255.76.67:7667?ttl=256", "an integer 0-255"),
        ("udpm://239.255.76.67:7667?ttl=-1", "an integer 0-255"),
        (
            "udpm://239.255.76.67:7667?ttl=yes",
            "an integer 0-255 (0 = this host only, 1 = the local network) for option ttl, not 'yes'",
        ),
        ("udpm://239.255.76.67:7667?ttl=0x1", "for option ttl"),
        ("udpm://239.255.76.67:7667?recv_buf_size=0", "a size in bytes"),
        ("udpm://239.255.76.67:7667?recv_buf_size=2MB", "a size in bytes"),
        ("udpm://239.255.76.67:7667?tll=1", "a known option of udpm:// (ttl, recv_buf_size), not 'tll'"),
        ("udpm://239.255.76.67:7667?transmit_only=1", "obsolete"),
        ("udpm://239.255.76.67:7667?ttl=1&ttl=0", "once"),
        ("mpudpm://239.255.76.67:65530?nports=10", "ports up to 65535"),
        ("mpudpm://239.255.76.67:7667?nports=0", "a number of ports"),
        ("memq://bus", "nothing after memq://"),
        ("memq://?ttl=0", "a known option of memq:// (none)"),
        ("file://", "the path of an LCM log"),
        ("file:///tmp/flight.lcm?mode=x", "r (read), w (write) or a (append) for option mode, not 'x'"),
        ("file:///tmp/flight.lcm?speed=fast", "a number for option speed"),
        ("file:///tmp/flight.lcm?speed=nan", "a number for option speed"),
        ("file:///tmp/flight.lcm?start_timestamp=-5", "microseconds"),
        ("file:///tmp/flight.lcm?ttl=0", "a known option of file://"),
        ("tcpq://127.0.0.1:70000", "a port 1-65535 after the host"),
        ("tcpq://bad host:7700", "a server HOST:PORT"),
    ],
)
def test_bad_bus_urls_name_the_bus(tmp_path: Path, url: str, expected: str) -> None:
    path = write(tmp_path, f'[buses]\nlocal = "memq://"\nlan = "{url}"\n')
    err = assert_config_error(path, "buses.lan", expected)
    assert err.expected.startswith("expected "), err.expected


def test_no_bus_at_all(tmp_path: Path) -> None:
    assert_config_error(write(tmp_path, "[buses]\n"), "buses", "at least one bus")


# ------------------------------------------------------------------ [osc] server


@pytest.mark.parametrize(
    "server",
    ["http://127.0.0.1:8080", "https://station.example", "http://[::1]:8080/", "https://op:8443/antalate"],
)
def test_station_urls_accepted(tmp_path: Path, server: str) -> None:
    assert load_config(write(tmp_path, f'[osc]\nserver = "{server}"\n')).osc.server == server


@pytest.mark.parametrize(
    ("server", "expected"),
    [
        ("127.0.0.1:8080", "an http:// or https:// URL"),
        ("ftp://station:21", "an http:// or https:// URL"),
        ("udpm://239.255.76.67:7667", "an http:// or https:// URL"),
        ("http://", "with a host"),
        ("http://:8080", "with a host"),
        ("http://station:99999", "a port 1-65535"),
        ("http://station:0", "a port 1-65535"),
        ("http://station:http", "a port 1-65535"),
        ("http://station:8080/?x=1", "without ?query"),
        ("", "an http:// or https:// URL"),
    ],
)
def test_bad_station_urls(tmp_path: Path, server: str, expected: str) -> None:
    err = assert_config_error(write(tmp_path, f'[osc]\nserver = "{server}"\n'), "osc.server", expected)
    assert err.expected.startswith("expected ") and err.expected.endswith(f"got {server!r}"), err.expected


# ------------------------------------------------------------------ autopilot names


def _installed_listed(message: str) -> None:
    from antalate_lcm.vehicles import available_adapters

    installed = available_adapters()
    assert {"sim", "tello", "mavlink"} <= set(installed)
    assert f"an installed adapter ({', '.join(installed)})" in message, message


@pytest.fixture
def plugin_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A directory on sys.path for throw-away adapter modules (unique names: imports are cached)."""
    d = tmp_path / "plugins"
    d.mkdir()
    monkeypatch.syspath_prepend(str(d))
    return d


@pytest.mark.parametrize(
    ("name", "detail"),
    [
        (":Foo", "'package.module:ClassName'"),
        (".sim:X", "an absolute module path"),
        ("sim:", "'package.module:ClassName'"),
        ("antalate_lcm.vehicles.sim:Sim Autopilot", "'package.module:ClassName'"),
        ("nope", "there is no adapter 'nope'"),
        ("Sim", "there is no adapter 'Sim'"),
        ("", "there is no adapter ''"),
        ("antalate_lcm.no_such_module:Foo", "No module named 'antalate_lcm.no_such_module'"),
        ("antalate_lcm.vehicles.sim:Nope", "has no attribute 'Nope'"),
        (
            "antalate_lcm.vehicles.base:VehicleState",
            "not a subclass of antalate_lcm.vehicles.base.VehicleAdapter",
        ),
        ("antalate_lcm.vehicles.base:VehicleAdapter", "abstract"),
    ],
)
def test_bad_autopilot_names_list_the_installed_adapters(tmp_path: Path, name: str, detail: str) -> None:
    err = assert_config_error(write(tmp_path, f'[hlc]\nautopilot = "{name}"\n'), "hlc.autopilot", detail)
    _installed_listed(err.expected)


def test_an_adapter_module_that_breaks_on_import(tmp_path: Path, plugin_dir: Path) -> None:
    (plugin_dir / "h4_broken_adapter.py").write_text("raise RuntimeError('needs a serial port at import')\n")
    (plugin_dir / "h4_syntax_adapter.py").write_text("class Broken(:\n")
    for module, detail in (
        ("h4_broken_adapter", "needs a serial port at import"),
        ("h4_syntax_adapter", "SyntaxError"),
    ):
        err = assert_config_error(
            write(tmp_path, f'[hlc]\nautopilot = "{module}:Adapter"\n'),
            "hlc.autopilot",
            f"importing {module} failed",
            detail,
        )
        _installed_listed(err.expected)


def test_design_style_table_names_its_name_key(tmp_path: Path) -> None:
    err = assert_config_error(
        write(tmp_path, '[hlc.autopilot]\nname = "simm"\n'), "hlc.autopilot.name", "'simm'"
    )
    _installed_listed(err.expected)


# ------------------------------------------------------------------ adapter params, by the adapter's own model


@pytest.mark.parametrize(("params", "field", "expected"), cases("core/sim_params.toml"))
@pytest.mark.parametrize("table", ["autopilot", "autopilot_params"])
def test_sim_params_are_validated_at_load(
    tmp_path: Path, table: str, params: str, field: str, expected: str
) -> None:
    name = 'name = "sim"\n' if table == "autopilot" else ""
    path = write(tmp_path, f"[hlc.{table}]\n{name}{params}\n")
    assert_config_error(path, f"hlc.{table}.{field}", expected)


def test_sim_params_model_covers_every_key_the_sim_accepts() -> None:
    """One truth: a knob added to the sim's DEFAULTS without its Params field fails here."""
    from antalate_lcm.vehicles.sim import DEFAULTS, Params, SimAdapter

    assert SimAdapter.params_model is Params
    assert Params().model_dump() == DEFAULTS
    assert Params.model_config.get("extra") == "forbid" and Params.model_config.get("strict") is True
    SimAdapter(dict(DEFAULTS))  # the documented defaults pass the adapter's own check


def test_sim_rejects_the_same_params_when_constructed_directly() -> None:
    from antalate_lcm.base.strict import StrictError
    from antalate_lcm.vehicles.sim import SimAdapter

    with pytest.raises(StrictError) as info:
        SimAdapter({"land_disarm_delay": -1.0})
    assert isinstance(info.value, ValueError) and info.value.key == "land_disarm_delay"


def test_any_adapter_declares_its_params_model(tmp_path: Path, plugin_dir: Path) -> None:
    """The mechanism, not just the sim: a third-party adapter's model names its own fields."""
    (plugin_dir / "h4_custom_adapter.py").write_text(
        "from typing import Literal\n"
        "from pydantic import BaseModel, ConfigDict, Field\n"
        "from antalate_lcm.vehicles.sim import SimAdapter\n"
        "class Params(BaseModel):\n"
        "    model_config = ConfigDict(extra='forbid', strict=True)\n"
        "    port: int = Field(default=14550, ge=1, le=65535)\n"
        "    mode: str = 'GUIDED'\n"
        "    sign: Literal[1, -1] | None = None\n"
        "class Custom(SimAdapter):\n"
        "    params_model = Params\n"
        "    def __init__(self, params=None, **kw):\n"
        "        super(SimAdapter, self).__init__(params, **kw)\n"
        "class Unchecked(SimAdapter):\n"
        "    params_model = None\n"
        "    def __init__(self, params=None, **kw):\n"
        "        if set(params or {}) - {'home_lat'}:\n"
        "            raise ValueError(f'unknown parameter(s) {sorted(params)}')\n"
        "        super().__init__(params, **kw)\n"
        "class Rude(Unchecked):\n"
        "    def __init__(self, params=None, **kw):\n"
        "        raise OSError('opened /dev/ttyACM0 in the constructor')\n"
    )
    ok = load_config(
        write(
            tmp_path, '[hlc]\nautopilot = "h4_custom_adapter:Custom"\n[hlc.autopilot_params]\nport = 5760\n'
        )
    )
    assert ok.hlc.autopilot_params == {"port": 5760}
    for params, field, expected in (
        ("port = '5760'", "port", "valid integer, got '5760'"),
        ("port = 70000", "port", "less than or equal to 65535"),
        ("prot = 5760", "prot", "Extra inputs"),
        ("sign = true", "sign", "Input should be 1 or -1, got True"),  # pydantic alone takes True for 1
    ):
        text = f'[hlc.autopilot]\nname = "h4_custom_adapter:Custom"\n{params}\n'
        assert_config_error(write(tmp_path, text), f"hlc.autopilot.{field}", expected)
    # without a model, the adapter's constructor is the check (no I/O before connect())
    err = assert_config_error(
        write(
            tmp_path, '[hlc]\nautopilot = "h4_custom_adapter:Unchecked"\n[hlc.autopilot_params]\nnope = 1\n'
        ),
        "hlc.autopilot_params",
    )
    assert "nope" in err.expected
    err = assert_config_error(
        write(tmp_path, '[hlc]\nautopilot = "h4_custom_adapter:Rude"\n'), "hlc.autopilot_params"
    )
    assert "its constructor failed" in err.expected and "/dev/ttyACM0" in err.expected


# ------------------------------------------------------------------ behaviors' params are strict too


@pytest.mark.parametrize(("params", "key", "expected"), cases("core/behavior_params.toml"))
def test_behavior_params_are_strict(tmp_path: Path, params: str, key: str, expected: str) -> None:
    from antalate_lcm.runtime.agent import validate

    behavior = DOVRAT if "turn_direction" in params or "detection_source" in params else BEHAVIOR
    config = load_config(write(tmp_path, behavior + f"params = {params}\n"))
    with pytest.raises(ConfigError) as info:
        validate(config)
    assert info.value.key == f"bma[0].behaviors[0].params.{key}" and expected in info.value.expected


def test_behavior_params_accept_what_toml_can_say(tmp_path: Path) -> None:
    """Strict JSON-like validation: an int fills a float, an array fills a list."""
    from antalate_lcm.agent.bma import plan_bma

    config = load_config(write(tmp_path, BEHAVIOR + "params = { retry = 3, max_flights = 1 }\n"))
    params = plan_bma(config, config.bma[0]).behaviors[0].params
    assert params.retry == 3.0 and params.max_flights == 1  # type: ignore[attr-defined]


# ------------------------------------------------------------------ agent names, unique per process


def _named(tmp_path: Path, file: str, name: str) -> Config:
    p = tmp_path / file
    p.write_text(
        f'[agent]\nname = "{name}"\n[buses]\nlan = "memq://"\n' if name else '[buses]\nlan = "memq://"\n'
    )
    return load_config(p)


def test_duplicate_agent_names_name_the_file_and_key(tmp_path: Path) -> None:
    a, b = _named(tmp_path, "a.toml", "uav"), _named(tmp_path, "b.toml", "uav")
    with pytest.raises(ConfigError) as info:
        check_unique_agent_names([a, b])
    err = info.value
    assert (err.file, err.key) == (b.source, "agent.name")
    assert "'uav' is also an agent of " + a.source in err.expected and "\n" not in str(err)
    with pytest.raises(ConfigError, match="the same file twice"):
        check_unique_agent_names([a, a])


def test_agents_n_naming_can_collide(tmp_path: Path) -> None:
    from antalate_lcm.runtime.agent import swarm_configs

    a, b = _named(tmp_path, "a.toml", "uav"), _named(tmp_path, "b.toml", "uav-02")
    configs = [*swarm_configs(a, 3), *swarm_configs(b, 1)]
    with pytest.raises(ConfigError) as info:
        check_unique_agent_names(configs, agents=3)
    assert info.value.file == b.source and info.value.key == "agent.name"
    assert "'uav-02'" in info.value.expected and "--agents 3" in info.value.expected
    # two unnamed configs copied N times both become sim-01, sim-02, ...
    anon = [
        *swarm_configs(_named(tmp_path, "c.toml", ""), 2),
        *swarm_configs(_named(tmp_path, "d.toml", ""), 2),
    ]
    with pytest.raises(ConfigError, match="'sim-01' is also an agent of .*c.toml"):
        check_unique_agent_names(anon, agents=2)
    check_unique_agent_names(
        [*swarm_configs(a, 3), *swarm_configs(_named(tmp_path, "e.toml", "ugv"), 3)], agents=3
    )


def test_lan_examples_have_distinct_agent_names() -> None:
    configs = [load_config(p) for p in sorted((REPO / "examples" / "lan").glob("*.toml"))]
    assert len(configs) >= 6
    check_unique_agent_names(configs)


def test_strict_validation_takes_toml_values_as_written() -> None:
    """What TOML can say fills any model (tuple, Enum, Path, nested); nothing is guessed."""
    import enum
    from typing import Literal

    from pydantic import BaseModel, ConfigDict

    from antalate_lcm.base.strict import StrictError, validate_strict

    class Mode(enum.Enum):
        FAST = "fast"

    class Inner(BaseModel):
        sign: Literal[1, -1] = 1

    class Model(BaseModel):
        model_config = ConfigDict(extra="forbid", strict=True)
        pair: tuple[int, int] = (0, 0)
        mode: Mode = Mode.FAST
        path: Path = Path(".")
        rate: float = 1.0
        inner: Inner = Inner()

    m = validate_strict(
        Model, {"pair": [1, 2], "mode": "fast", "path": "/tmp/x", "rate": 3, "inner": {"sign": -1}}
    )
    assert (m.pair, m.mode, m.path, m.rate, m.inner.sign) == ((1, 2), Mode.FAST, Path("/tmp/x"), 3.0, -1)
    for data, key, message in (
        ({"pair": ["1", 2]}, "pair[0]", "valid integer"),
        ({"mode": "slow"}, "mode", "'fast'"),
        ({"rate": "3"}, "rate", "valid number"),
        ({"inner": {"sign": True}}, "inner.sign", "1 or -1, got True"),
        ({"inner": {"sign": 2}}, "inner.sign", "1 or -1"),
        ({"rate": float("nan"), "extra": 1}, "extra", "Extra inputs"),
    ):
        with pytest.raises(StrictError) as info:
            validate_strict(Model, data)
        assert info.value.key == key and message in info.value.message, (data, str(info.value))


@pytest.mark.parametrize("adapter", ["sim", "tello", "mavlink"])
def test_every_shipped_adapter_declares_a_strict_params_model(tmp_path: Path, adapter: str) -> None:
    from antalate_lcm.vehicles import load_adapter

    model = load_adapter(adapter).params_model
    assert model is not None, f"{adapter}: no params_model"
    assert model.model_config.get("extra") == "forbid" and model.model_config.get("strict") is True
    number = next(n for n, f in model.model_fields.items() if f.annotation in (int, float))
    for value, expected in (("'1'", "valid "), ("true", "valid ")):
        text = f'[hlc.autopilot]\nname = "{adapter}"\n{number} = {value}\n'
        assert_config_error(write(tmp_path, text), f"hlc.autopilot.{number}", expected)
    assert_config_error(
        write(tmp_path, f'[hlc]\nautopilot = "{adapter}"\n[hlc.autopilot_params]\nno_such_key = 1\n'),
        "hlc.autopilot_params.no_such_key",
        "Extra inputs",
    )
