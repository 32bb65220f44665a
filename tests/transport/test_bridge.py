"""antalate bridge: its pure parts, its config, and two bridges on one Zenoh bus with real multicast
LANs in a private namespace (tests/wan/bridge_scenario.py)."""

from __future__ import annotations

import json
import socket
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from antalate_lcm.apps.bridge import Bridge, BridgeConfig, Direction, Memory, Throttle, load_bridge_config
from antalate_lcm.base.errors import ConfigError
from antalate_lcm.transports.zenoh import BRIDGE_MARK
from antalate_lcm.transports.zenoh.groups import _Group
from antalate_lcm.wire.security import MemberProof
from tests import REPO
from tests.harness.netns import NetNamespace

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install -e '.[dev]')")


# ------------------------------------------------------------------------------------ pure parts
def test_memory_knows_a_message_for_its_window_only() -> None:
    m = Memory(2.0)
    k = Memory.digest("alpha/MC_STATE", b"abc")
    assert not m.check_and_add(k, 100.0)
    assert m.check_and_add(k, 101.0)  # the echo, or a second bridge's copy
    assert not m.check_and_add(Memory.digest("beta/MC_STATE", b"abc"), 101.0)  # same bytes, other channel
    assert not m.check_and_add(k, 103.5)  # forgotten: 2.5 s after it was last seen
    m.check_and_add(Memory.digest("x", b"y"), 200.0)
    assert len(m) == 1  # old entries are dropped, memory stays bounded by the window


def test_throttle_keeps_the_newest_and_sends_it_at_the_next_slot() -> None:
    t = Throttle(rate=2.0)  # one per 0.5 s
    assert t.offer("a/TELEMETRY", b"1", 10.0)
    assert not t.offer("a/TELEMETRY", b"2", 10.1)
    assert not t.offer("a/TELEMETRY", b"3", 10.2)  # replaces 2: a state topic ends on its latest value
    assert t.offer("b/TELEMETRY", b"x", 10.2)  # each channel has its own slot
    assert t.due(10.3) == []
    assert t.due(10.5) == [("a/TELEMETRY", b"3")]
    assert t.superseded == 1
    assert t.due(11.5) == []  # nothing waits
    assert not t.offer("a/TELEMETRY", b"4", 10.9)
    assert t.due(11.0) == [("a/TELEMETRY", b"4")]


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "bridge.toml"
    p.write_text(text)
    return p


GOOD = """
[buses]
lan = "udpm://239.255.76.67:7667?ttl=1"
wan = "zenoh://?connect=tcp/192.0.2.10:7447"

[bridge]
between = ["lan", "wan"]
exclude = [".*/VIDEO"]

[[bridge.limit]]
channel = ".*/TELEMETRY"
to = "wan"
rate = 2.0
"""


def test_the_example_configs_load() -> None:
    for path in sorted((REPO / "examples" / "wan").glob("*bridge*.toml")):
        config = load_bridge_config(path)
        assert len(config.bridge.between) == 2


def test_a_good_config_loads(tmp_path: Path) -> None:
    config = load_bridge_config(_write(tmp_path, GOOD))
    assert config.bridge.channels == [".*"]  # everything by default
    assert config.bridge.limit[0].rate == 2.0


@pytest.mark.parametrize(
    ("change", "key", "expected"),
    [
        (('between = ["lan", "wan"]', 'between = ["lan", "lan"]'), "bridge.between", "two different buses"),
        (
            ('between = ["lan", "wan"]', 'between = ["lan", "radio"]'),
            "bridge.between",
            "a bus declared in [buses]",
        ),
        (('to = "wan"', 'to = "cloud"'), "bridge.limit[0].to", "one of lan, wan"),
        (("rate = 2.0", "rate = 0"), "bridge.limit.0.rate", "greater than 0"),
        (
            ('wan = "zenoh://?connect=tcp/192.0.2.10:7447"', 'wan = "zenoh://?connect=192.0.2.10:7447"'),
            "buses",
            "Zenoh endpoint",
        ),
        (('exclude = [".*/VIDEO"]', 'exclude = ["(unclosed"]'), "bridge", "regular expression"),
        (('exclude = [".*/VIDEO"]', 'excluded = [".*/VIDEO"]'), "bridge.excluded", "Extra inputs"),
    ],
)
def test_config_mistakes_name_the_key(
    tmp_path: Path, change: tuple[str, str], key: str, expected: str
) -> None:
    with pytest.raises(ConfigError) as err:
        load_bridge_config(_write(tmp_path, GOOD.replace(*change)))
    assert err.value.key.startswith(key.split(".")[0]), err.value
    assert expected in str(err.value), err.value


def test_a_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such file"):
        load_bridge_config(tmp_path / "nope.toml")


# ------------------------------------------------------------------- two bridges, real networks
def _scenario(netns: NetNamespace, name: str) -> dict[str, Any]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # free on the host; the namespace's loopback is empty anyway
    proc = netns.python(
        "-m",
        "tests.wan.bridge_scenario",
        name,
        str(port),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=str(REPO),
    )
    out, err = proc.communicate(timeout=90)
    assert proc.returncode == 0, err[-3000:]
    summary: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    return summary


def test_two_sites_get_everything_once_and_nothing_loops(netns: NetNamespace) -> None:
    r = _scenario(netns, "two-sites")
    assert r["all_arrived"] and r["fenced"]
    for where in ("a", "b", "w"):  # LAN A, LAN B and a Zenoh subscriber
        assert r["observers"][where] == {"distinct": 120, "max_copies": 1, "total": 120}, where
    # Each bridge forwarded its own side's messages (40 + probes) and nothing it had put itself.
    a, b = r["bridges"]
    assert a["lan->wan"] < 60 and b["lan->wan"] < 60 + r["telemetry"]["sent"], r["bridges"]


def test_the_uplink_cap_lets_the_rate_through_and_ends_on_the_newest(netns: NetNamespace) -> None:
    tel = _scenario(netns, "two-sites")["telemetry"]
    assert tel["newest_arrived"] and tel["last_is_newest"]
    # At most one per slot, plus the first and the newest one sent at the end.
    assert 1 <= tel["received"] <= int(tel["elapsed"] * tel["rate"]) + 2, tel
    assert tel["received"] < tel["sent"]


def test_two_bridges_on_one_lan_deliver_once_each_way_and_fail_over(netns: NetNamespace) -> None:
    """A redundant site gateway: both bridges share [bridge] site."""
    r = _scenario(netns, "one-lan")
    assert r["arrived"] and r["fenced"]
    assert r["lan_copies_of_a_lan_message"] == 1  # never forwarded back to where it came from
    assert r["wan_copies_of_a_lan_message"] == 1  # the Zenoh side drops the second bridge's copy
    assert r["lan_copies_of_a_wan_message"] == 1  # only the elected bridge forwards to the LAN
    standby = [b for b in r["bridges"] if b["wan->lan"] == 0]
    assert len(standby) == 1 and standby[0]["not_forwarded_standby"] > 0, r["bridges"]
    # The elected bridge stops: the other one forwards from then on, still once.
    assert r["took_over"] and r["lan_copies_after_failover"] == 1


# ------------------------------------------------------------------- any message, never an exception
@pytest.fixture(scope="module")
def loop_bridge() -> Iterator[Bridge]:
    """A real bridge between an in-process LCM bus and a Zenoh peer listening on loopback."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    config = BridgeConfig.model_validate(
        {
            "buses": {"lan": "memq://", "wan": f"zenoh://?listen=tcp/127.0.0.1:{port}&mode=peer"},
            "bridge": {"between": ["lan", "wan"]},
        }
    )
    bridge = Bridge(config)
    bridge.start()
    yield bridge
    bridge.close()


def _accounted(d: Direction) -> int:
    throttled = sum(t.superseded for _, t in d.limits)
    return (
        d.forwarded
        + d.not_selected
        + sum(d.dropped.values())
        + d.seen
        + d.same_origin
        + d.standby
        + throttled
    )


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    source=st.sampled_from(["lan", "wan"]),
    channel=st.one_of(st.text(max_size=80), st.sampled_from(["", "\0", "a\0b", "t/x", "c" * 64])),
    data=st.binary(max_size=3000),
    attachment=st.one_of(
        st.none(), st.binary(max_size=64), st.binary(max_size=40).map(lambda b: BRIDGE_MARK + b)
    ),
)
def test_any_message_is_forwarded_or_counted_never_raised(
    loop_bridge: Bridge, source: str, channel: str, data: bytes, attachment: bytes | None
) -> None:
    """Issue 29.1 as a property: keys, attachments and payloads as an outsider may send them."""
    d = loop_bridge.directions[source]
    before = _accounted(d)
    loop_bridge._on_message(source, channel, data, attachment)  # raises nothing, whatever it holds
    if source == "wan":  # exactly one outcome (the LAN side also hears the copies looped back to it)
        assert _accounted(d) == before + 1
    else:
        assert _accounted(d) >= before + 1
    assert all(t.is_alive() for t in loop_bridge._threads)


# ------------------------------------------------------------------------------ the election's tokens
def test_a_member_token_is_believed_only_when_signed_and_fresh() -> None:
    proof = MemberProof(("k1", "k0"), window=5.0, refresh=1.0)
    name = proof.token("g", "abc123", 1000.0)
    assert proof.check("g", name, 1000.5) == ("abc123", 1000.0)
    assert MemberProof(("k0", "k1")).check("g", name, 1000.5) == ("abc123", 1000.0)  # rotation: both check
    assert "MAC" in str(MemberProof(("other",)).check("g", name, 1000.5))
    assert "MAC" in str(proof.check("other-group", name, 1000.5))  # not valid in another site's group
    assert "stale" in str(proof.check("g", name, 1007.0))
    assert "not a signed" in str(proof.check("g", "0", 1000.0))


def test_a_group_counts_signed_members_and_forgets_stale_ones() -> None:
    reported: list[frozenset[str]] = []
    proof = MemberProof(("k",), window=5.0, refresh=1.0)
    g = _Group("p-groups/g", "g", "me", reported.append, proof)
    assert g.seen("0", True, 100.0) is not None  # the outsider's token of issue 29.3
    assert g.seen(proof.token("g", "zz", 100.0), True, 100.0) is None
    g.report()
    assert reported == [frozenset({"me", "zz"})]
    g.expire(106.5)  # zz stopped refreshing: gone after window + refresh
    g.report()
    assert reported[-1] == frozenset({"me"})
