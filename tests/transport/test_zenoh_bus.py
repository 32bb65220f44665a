"""The zenoh:// bus: the same typed messages as udpm://, through a real Zenoh router on loopback."""

from __future__ import annotations

import logging
import select
import socket
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

zenoh = pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install -e '.[dev]')")

from antalate_lcm.base.errors import ConfigError  # noqa: E402
from antalate_lcm.core.bus import Buses  # noqa: E402
from antalate_lcm.core.config import load_config  # noqa: E402
from antalate_lcm.msgs import mc_state_t, telemetry_t  # noqa: E402
from antalate_lcm.runtime.router import router_config  # noqa: E402
from antalate_lcm.transports.zenoh import ZenohLCM, channel_key, key_channel, literal_channel  # noqa: E402
from tests import REPO  # noqa: E402
from tests.harness.messages import mc_state  # noqa: E402
from tests.harness.polling import wait_for  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Router:
    def __init__(self, port: int) -> None:
        self.port = port
        self.endpoint = f"tcp/127.0.0.1:{port}"
        self.session: Any = None

    def start(self) -> Router:
        self.session = zenoh.open(router_config([self.endpoint], 3000))
        return self

    def stop(self) -> None:
        if self.session is not None:
            self.session.close()
            self.session = None


@pytest.fixture
def router() -> Iterator[Router]:
    r = Router(free_port()).start()
    yield r
    r.stop()


def url(r: Router, extra: str = "") -> str:
    return f"zenoh://?connect={r.endpoint}{extra}"


@pytest.fixture
def buses(router: Router) -> Iterator[tuple[Buses, Buses]]:
    a, b = Buses({"wan": url(router)}), Buses({"wan": url(router)})
    yield a, b
    a.close()
    b.close()


PROBE_SEQ = 999_999
PROBE = mc_state(0, seq=PROBE_SEQ)


def _settle(pub: Buses, sub_bus: Buses, channel: str, got: list[Any]) -> None:
    """Publish probes until the subscription has reached the router (Zenoh declares asynchronously).

    Probes still in flight may arrive later: the handlers of these tests ignore them (``probe``)."""

    def send() -> bool:
        pub.publish("wan", channel, PROBE)
        return bool(got)

    seen: list[Any] = []
    sub = sub_bus.subscribe("wan", channel, None, lambda ch, d: seen.append(d))
    assert wait_for(lambda: send() or seen, 10, 0.05), (
        "the subscription never saw a message through the router"
    )
    sub_bus.unsubscribe(sub)


def probe(m: Any) -> bool:
    return m == PROBE.encode() if isinstance(m, bytes) else m.header.seq == PROBE_SEQ


def past_probe(handler: Callable[[str, Any], object]) -> Callable[[str, Any], None]:
    """A subscriber that passes on every message but the settling probe."""

    def on(channel: str, msg: Any) -> None:
        if not probe(msg):
            handler(channel, msg)

    return on


# ---------------------------------------------------------------------------------- pure parts
@pytest.mark.parametrize(
    "channel",
    [
        "alpha/MC_STATE",
        "OPERATOR_CMD",
        "a//b",
        "/lead",
        "trail/",
        "x*y",
        "what?",
        "$sys",
        "#1",
        "50%",
        "a b",
        "@v",
        "ü/ß",
    ],
)
def test_every_channel_has_a_key_and_back(channel: str) -> None:
    key = channel_key("antalate", channel)
    zenoh.KeyExpr(key)  # a valid key, no wildcard
    assert "*" not in key and "$" not in key
    assert key_channel("antalate", key) == channel


def test_only_literal_regexes_get_an_exact_key() -> None:
    assert literal_channel(r"alpha/MC\.STATE") == "alpha/MC.STATE"
    assert literal_channel("alpha/MC_STATE") == "alpha/MC_STATE"
    assert literal_channel(".*") is None
    assert literal_channel("(alpha|beta)/TELEMETRY") is None


@pytest.mark.parametrize(
    "good",
    [
        "zenoh://",
        "zenoh://?connect=tcp/127.0.0.1:7447",
        "zenoh://swarm1?connect=tcp/192.0.2.1:7447,tcp/router.example:7447&mode=client&lease=5000",
        "zenoh://?listen=tcp/0.0.0.0:7448&mode=peer&express=1&scout=0",
        "zenoh://?connect=tcp/[::1]:7447",
    ],
)
def test_zenoh_urls_are_accepted(tmp_path: Path, good: str) -> None:
    (tmp_path / "c.toml").write_text(f'[buses]\nlan = "{good}"\n')
    assert load_config(tmp_path / "c.toml").buses["lan"] == good


@pytest.mark.parametrize(
    ("bad", "expected"),
    [
        ("zenoh://?connect=127.0.0.1:7447", "a Zenoh endpoint PROTOCOL/HOST:PORT"),
        ("zenoh://?connect=tcp/127.0.0.1", "HOST:PORT after tcp/"),
        ("zenoh://?connect=tcp/127.0.0.1:99999", "a port 1-65535 in option connect"),
        ("zenoh://?connect=", "Zenoh endpoints for option connect"),
        ("zenoh://?mode=router", "peer or client for option mode"),
        ("zenoh://?mode=client", "option connect with mode=client"),
        ("zenoh://a*b", "a Zenoh key prefix"),
        ("zenoh://a//b", "a Zenoh key prefix"),
        ("zenoh://?express=yes", "0 or 1 for option express"),
        ("zenoh://?lease=10", "a link lease in milliseconds"),
        ("zenoh://?ttl=1", "a known option of zenoh://"),
    ],
)
def test_bad_zenoh_urls_say_what_was_expected(tmp_path: Path, bad: str, expected: str) -> None:
    (tmp_path / "c.toml").write_text(f'[buses]\nlan = "{bad}"\n')
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path / "c.toml")
    assert err.value.key == "buses.lan"
    assert expected in err.value.expected


# --------------------------------------------------------------------------- through a router
def test_typed_messages_cross_the_router_as_the_exact_lcm_bytes(buses: tuple[Buses, Buses]) -> None:
    a, b = buses
    typed: list[mc_state_t] = []
    raw: list[bytes] = []
    b.subscribe("wan", "alpha/MC_STATE", mc_state_t, past_probe(lambda ch, m: typed.append(m)))
    b.subscribe("wan", "alpha/MC_STATE", None, past_probe(lambda ch, d: raw.append(d)))
    _settle(a, b, "alpha/MC_STATE", typed)
    msg = mc_state(mc_state_t.MISSION, seq=7)
    assert a.publish("wan", "alpha/MC_STATE", msg)
    assert wait_for(lambda: typed and raw, 10)
    assert typed[0].state == mc_state_t.MISSION and typed[0].header.seq == 7
    assert raw == [msg.encode()]  # fingerprint and header.mac included: signing works unchanged


def test_regex_subscription_sees_every_agent_and_nothing_else(buses: tuple[Buses, Buses]) -> None:
    a, b = buses
    got: list[str] = []
    b.subscribe("wan", ".*/MC_STATE", mc_state_t, past_probe(lambda ch, m: got.append(ch)), regex=True)
    _settle(a, b, "zz/MC_STATE", got)
    for name in ("alpha", "beta", "gamma"):
        a.publish("wan", f"{name}/MC_STATE", mc_state(1))
    a.publish("wan", "alpha/TELEMETRY", telemetry_t())
    assert wait_for(lambda: len(got) >= 3, 10)
    assert sorted(got) == ["alpha/MC_STATE", "beta/MC_STATE", "gamma/MC_STATE"]


def test_garbage_is_counted_as_on_udpm(buses: tuple[Buses, Buses], caplog: pytest.LogCaptureFixture) -> None:
    a, b = buses
    got: list[mc_state_t] = []
    b.subscribe("wan", "alpha/MC_STATE", mc_state_t, past_probe(lambda ch, m: got.append(m)))
    _settle(a, b, "alpha/MC_STATE", got)
    with caplog.at_level(logging.WARNING, logger="antalate.bus"):
        for _ in range(5):
            a.publish("wan", "alpha/MC_STATE", b"\x00garbage")
        a.publish("wan", "alpha/MC_STATE", mc_state(2))
        assert wait_for(lambda: got, 10)
    assert b.decode_errors() == {"alpha/MC_STATE": 5}
    assert got[0].state == 2  # the bus carried on
    assert any("not a valid mc_state_t" in r.getMessage() for r in caplog.records)


def test_a_burst_is_not_dropped(buses: tuple[Buses, Buses]) -> None:
    a, b = buses
    got: list[int] = []
    b.subscribe("wan", "alpha/MC_STATE", mc_state_t, past_probe(lambda ch, m: got.append(m.header.seq)))
    _settle(a, b, "alpha/MC_STATE", got)
    for i in range(3000):
        a.publish("wan", "alpha/MC_STATE", mc_state(1, seq=i))
    assert wait_for(lambda: len(got) >= 3000, 20)
    assert got == list(range(3000))  # in order, none lost, none twice


def test_own_publications_reach_own_subscribers_as_on_multicast(router: Router) -> None:
    """Two nodes of one process share the bus: one's publication must reach the other."""
    with Buses({"wan": url(router)}) as bus:
        got: list[mc_state_t] = []
        bus.subscribe("wan", "alpha/MC_STATE", mc_state_t, lambda ch, m: got.append(m))
        bus.publish("wan", "alpha/MC_STATE", mc_state(3))
        assert wait_for(lambda: got, 10)


def test_unsubscribe_inside_a_handler(buses: tuple[Buses, Buses]) -> None:
    a, b = buses
    got: list[int] = []
    sub: list[Any] = []

    def once(ch: str, m: mc_state_t) -> None:
        if probe(m):
            return
        got.append(m.header.seq)
        b.unsubscribe(sub[0])

    keep: list[int] = []
    b.subscribe("wan", "alpha/MC_STATE", mc_state_t, past_probe(lambda ch, m: keep.append(m.header.seq)))
    _settle(a, b, "alpha/MC_STATE", keep)
    sub.append(b.subscribe("wan", "alpha/MC_STATE", mc_state_t, once))
    for i in range(1, 6):
        a.publish("wan", "alpha/MC_STATE", mc_state(1, seq=i))
    assert wait_for(lambda: len(keep) >= 5, 10)
    assert len(got) == 1


def test_fileno_is_readable_exactly_while_a_message_waits(router: Router) -> None:
    """So an event loop can wait on every bus's fileno() instead of a thread per bus."""
    z = ZenohLCM(url(router))
    try:
        got: list[tuple[str, bytes]] = []
        z.subscribe("alpha/X", lambda ch, d: got.append((ch, d)))
        assert select.select([z.fileno()], [], [], 0)[0] == []
        z.publish("alpha/X", b"one")
        z.publish("alpha/X", b"two")
        assert select.select([z.fileno()], [], [], 10)[0] == [z.fileno()]
        assert z.handle_timeout(1000) == 1  # one message per call, as liblcm's
        assert select.select([z.fileno()], [], [], 10)[0] == [z.fileno()]  # the second one still waits
        assert z.handle_timeout(1000) == 1
        assert got == [("alpha/X", b"one"), ("alpha/X", b"two")]
        assert select.select([z.fileno()], [], [], 0)[0] == []
    finally:
        z.close()


def test_an_agent_starts_before_its_router_and_is_heard_once_it_answers() -> None:
    """A vehicle may boot before its LTE link: the bus opens, sends fail (counted), then work."""
    r = Router(free_port())
    bus = Buses({"wan": url(r)})
    try:
        bus.open()  # does not raise: the router is not there yet
        assert not bus.publish("wan", "alpha/MC_STATE", mc_state(1))
        assert bus.publish_errors == 1
        r.start()
        with Buses({"wan": url(r)}) as listener:
            got: list[mc_state_t] = []
            listener.subscribe("wan", "alpha/MC_STATE", mc_state_t, lambda ch, m: got.append(m))
            assert wait_for(lambda: bus.publish("wan", "alpha/MC_STATE", mc_state(1)) and got, 15, 0.2)
    finally:
        bus.close()
        r.stop()


def test_the_router_restarting_is_survived(router: Router) -> None:
    a, b = Buses({"wan": url(router)}), Buses({"wan": url(router)})
    try:
        got: list[mc_state_t] = []
        b.subscribe("wan", "alpha/MC_STATE", mc_state_t, lambda ch, m: got.append(m))
        _settle(a, b, "alpha/MC_STATE", got)
        router.stop()
        router.start()
        # Seen again once both clients have reconnected (retry period <= 1 s).
        assert wait_for(lambda: a.publish("wan", "alpha/MC_STATE", mc_state(5)) and got, 15, 0.1)
    finally:
        a.close()
        b.close()


def test_a_closed_transport_says_so_and_closing_twice_is_fine(router: Router) -> None:
    """The bus's loop stops reading a provider that raises OSError (as for a finished file:// log)."""
    z = ZenohLCM(url(router))
    z.subscribe("alpha/X", lambda ch, d: None)
    z.close()
    z.close()
    with pytest.raises(OSError, match="closed"):
        z.handle_timeout(0)
    with pytest.raises(OSError):
        z.publish("alpha/X", b"late")


def test_the_lcm_tools_refuse_a_zenoh_bus_with_the_way_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """lcm-logger and lcm-spy speak LCM only: `antalate log`/`spy` on a zenoh bus say to bridge it."""
    from antalate_lcm.base.errors import BusUnavailable
    from antalate_lcm.cli import main
    from antalate_lcm.transports import open_lcm

    with pytest.raises(BusUnavailable, match="antalate bridge"):
        open_lcm("zenoh://?connect=tcp/127.0.0.1:7447")
    (tmp_path / "c.toml").write_text('[buses]\nlan = "zenoh://?connect=tcp/127.0.0.1:7447"\n')
    for command in (
        ["log", str(tmp_path / "c.toml"), "-o", str(tmp_path / "x.lcm")],
        ["spy", str(tmp_path / "c.toml")],
    ):
        assert main(command) == 2
        assert "antalate bridge" in capsys.readouterr().err


def test_a_slow_handler_drops_beyond_its_queue_and_counts(router: Router) -> None:
    """As LCM does: memory stays bounded when a fast link feeds a handler that does not keep up."""
    z = ZenohLCM(url(router))
    try:
        got: list[bytes] = []
        sub = z.subscribe("alpha/X", lambda ch, d: got.append(d))
        sub.set_queue_capacity(5)
        z.publish("alpha/X", b"first")  # nobody handles: it waits in the queue
        assert wait_for(lambda: sub.pending == 1, 10)
        for i in range(49):
            z.publish("alpha/X", b"%d" % i)
        assert wait_for(lambda: sub.pending + sub.dropped == 50, 10)
        assert sub.pending == 5 and sub.dropped == 45 == z.dropped
        while z.handle_timeout(0):
            pass
        assert got == [b"first", b"0", b"1", b"2", b"3"]  # the oldest kept, in order
    finally:
        z.close()


def test_the_router_command_says_what_is_wrong(capsys: pytest.CaptureFixture[str]) -> None:
    from antalate_lcm.cli import main

    assert main(["router", "--listen", "tcp/127.0.0.1"]) == 2
    assert "HOST:PORT" in capsys.readouterr().err
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        assert main(["router", "--listen", f"tcp/127.0.0.1:{busy.getsockname()[1]}"]) == 2
    assert "cannot listen" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["agent_zenoh.toml", "operator_remote.toml"])
def test_the_wan_example_configs_load(name: str) -> None:
    config = load_config(REPO / "examples" / "wan" / name)
    assert any(u.startswith("zenoh://") for u in config.buses.values())


def test_a_message_two_bridges_forwarded_is_delivered_once_and_plain_repeats_are_not_touched(
    router: Router,
) -> None:
    from antalate_lcm.transports.zenoh import BRIDGE_MARK

    pub, z = ZenohLCM(url(router)), ZenohLCM(url(router))
    try:
        got: list[bytes] = []
        z.subscribe("alpha/X", lambda ch, d: got.append(d))

        def settled() -> bool:
            pub.publish("alpha/X", b"probe")
            z.handle_timeout(50)
            return bool(got)

        assert wait_for(settled, 10)
        pub.publish("alpha/X", b"same", attachment=BRIDGE_MARK + b"bridge-1:aaaa")
        pub.publish(
            "alpha/X", b"same", attachment=BRIDGE_MARK + b"bridge-2:aaaa"
        )  # the second gateway's copy
        pub.publish("alpha/X", b"plain")
        pub.publish("alpha/X", b"plain")  # not forwarded by a bridge: the bus never judges
        pub.publish("alpha/X", b"end")
        assert wait_for(lambda: z.handle_timeout(50) >= 0 and b"end" in got, 10)
        assert [d for d in got if d != b"probe"] == [b"same", b"plain", b"plain", b"end"]
    finally:
        pub.close()
        z.close()
