"""The simulated LAN itself: multicast across the switch, loss, a cut link, and a clean teardown."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

import pytest

from tests.lan.swarm import LAN_URL, LOCAL_URL
from tests.lan.topology import PREFIX, Host, Lan, _namespaces, sweep_stale

pytestmark = [pytest.mark.lan, pytest.mark.timeout(60)]

#: The naive layout: the agent's own bus on the LAN's multicast route (ttl=0 still keeps it home).
NAIVE_LOCAL_URL = "udpm://239.255.76.67:7668?ttl=0"


def receiver(host: Host, url: str, seconds: float) -> subprocess.Popen[str]:
    proc = host.popen(
        [sys.executable, "-m", "tests.lan.mcast", "recv", url, str(seconds)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None
    assert json.loads(proc.stdout.readline()).get("ready"), proc.stderr.read() if proc.stderr else ""
    return proc


def sender(host: Host, url: str, n: int, period: float, channel: str = "TEST") -> subprocess.Popen[str]:
    return host.popen(
        [sys.executable, "-m", "tests.lan.mcast", "send", url, channel, str(n), str(period)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )


def result(proc: subprocess.Popen[str], timeout: float = 30) -> dict[str, Any]:
    out, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, err
    summary: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    return summary


def test_lan_bus_crosses_the_switch_and_the_local_bus_stays_home(make_lan: Callable[..., Lan]) -> None:
    lan = make_lan(3)
    h1, h2, h3 = lan["h1"], lan["h2"], lan["h3"]
    assert (h1.address, h3.address) == ("10.77.0.11", "10.77.0.13")
    rx = {
        (h.name, bus): receiver(h, url, 2.5)
        for h in (h1, h2, h3)
        for bus, url in (("lan", LAN_URL), ("local", LOCAL_URL))
    }
    sends = [sender(h1, LAN_URL, 50, 0.01, "L"), sender(h1, LOCAL_URL, 50, 0.01, "H")]
    assert all(result(s)["sent"] == 50 for s in sends)
    got = {key: result(p)["received"] for key, p in rx.items()}
    assert got[("h2", "lan")] == {"L": 50} and got[("h3", "lan")] == {"L": 50}
    assert got[("h1", "local")] == {"H": 50}
    assert got[("h2", "local")] == {} and got[("h3", "local")] == {}


def test_loss_on_the_switch(make_lan: Callable[..., Lan]) -> None:
    lan = make_lan(2)
    lan.set_loss(20)
    rx = receiver(lan["h2"], LAN_URL, 8.0)  # 1,000 at 2 ms took over 4 s on a loaded machine
    assert result(sender(lan["h1"], LAN_URL, 1000, 0.002))["errors"] == 0  # the sender never notices
    received = result(rx)["received"].get("TEST", 0)
    assert 700 <= received <= 900, received
    assert lan.dropped() >= 1000 - received
    lan.set_loss(0)
    rx = receiver(lan["h2"], LAN_URL, 2.0)
    result(sender(lan["h1"], LAN_URL, 200, 0.002))
    assert result(rx)["received"] == {"TEST": 200}


def test_a_cut_host_keeps_its_local_bus_only_with_its_own_route(make_lan: Callable[..., Lan]) -> None:
    lan = make_lan(2)
    h1, h2 = lan["h1"], lan["h2"]
    rx_lan = receiver(h2, LAN_URL, 5.0)
    rx_local = receiver(h1, LOCAL_URL, 5.0)
    rx_naive = receiver(h1, NAIVE_LOCAL_URL, 5.0)
    # 3 s of traffic on each bus; the link is down from 1 s to 2 s
    tx = {
        bus: sender(h1, url, 150, 0.02)
        for bus, url in (("lan", LAN_URL), ("local", LOCAL_URL), ("naive", NAIVE_LOCAL_URL))
    }
    time.sleep(1.0)
    lan.cut("h1")
    assert "224.0.0.0/4" not in h1.routes()  # the kernel deleted the LAN's multicast route
    time.sleep(1.0)
    lan.restore("h1")
    assert "224.0.0.0/4 dev lan0" in h1.routes()
    sent = {bus: result(p) for bus, p in tx.items()}
    # the local bus on its own group routed to lo: not one send failed, every message arrived
    assert sent["local"]["errors"] == 0 and result(rx_local)["received"] == {"TEST": 150}
    # the LAN bus failed while cut ("Network is unreachable") and came back with the link
    assert 20 <= sent["lan"]["errors"] <= 100, sent["lan"]
    assert "unreachable" in sent["lan"]["error"].lower()
    assert 50 <= result(rx_lan)["received"]["TEST"] == sent["lan"]["sent"]
    # the naive local bus shared the LAN's route and went down with it
    assert sent["naive"]["errors"] >= 20
    assert result(rx_naive)["received"]["TEST"] == sent["naive"]["sent"] < 150


def test_teardown_removes_everything_even_when_the_test_fails() -> None:
    from tests.lan.conftest import lan_reason

    if lan_reason():
        pytest.skip(f"no simulated LAN: {lan_reason()}")
    with pytest.raises(RuntimeError, match="boom"), Lan(["a", "b"]) as lan:
        sleeper = lan["a"].popen(["sleep", "1000"])
        names = lan.namespaces()
        assert len(names) == 3
        raise RuntimeError("boom")
    assert not set(names) & set(_namespaces())
    assert sleeper.poll() is not None


def test_sweep_removes_only_namespaces_of_dead_runs(need_lan: None) -> None:
    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = f"{PREFIX}-{dead.pid}-abcdef-h1"
    mine = f"{PREFIX}-{__import__('os').getpid()}-abcdef-h1"
    for ns in (stale, mine):
        subprocess.run(["ip", "netns", "add", ns], check=True)
    try:
        removed = sweep_stale()
        assert stale in removed and mine not in removed
        assert stale not in _namespaces() and mine in _namespaces()
    finally:
        for ns in (stale, mine):
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True)
