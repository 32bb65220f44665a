"""An agent and an operator that talk Zenoh directly (examples/wan/agent_zenoh.toml and
operator_remote.toml), no LAN and no bridge: only the bus URLs differ from a LAN set-up.

Everything runs in a private namespace (the agent's own bus is multicast on lo): ``antalate router``
on loopback, ``antalate agent`` with the example config, and the LAN tests' operator (the console's
command tracker) on the example operator config. Three times: on ``tcp/``; through a router with
mutual TLS (``antalate lab-ca``; the agent and the operator each with a certificate of their own);
through a TLS router with a users file (each with its own ``auth=`` file) (issue 29 finding 7).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import tomli_w

from tests import REPO
from tests.harness.agents import FAST_SIM
from tests.harness.netns import NetNamespace
from tests.harness.process import run_antalate
from tests.lan.swarm import OperatorClient, _merge

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised only on 3.10
    import tomli as tomllib

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install -e '.[dev]')")

EXAMPLES = REPO / "examples" / "wan"
KEY = "zenoh-test-swarm-key"
PORT = 7447
URL = f"zenoh://?connect=tcp/127.0.0.1:{PORT}&mode=client"


def lab_ca(out: Path, *clients: str, host: str = "127.0.0.1") -> Path:
    """``antalate lab-ca``: a CA, the router's certificate for ``host`` and one per client."""
    args = [a for c in clients for a in ("--client", c)]
    made = run_antalate("lab-ca", str(out), "--host", host, *args, cwd=str(REPO))
    assert made.returncode == 0, made.stderr
    return out


def mtls_url(pki: Path, client: str, endpoint: str) -> str:
    """A zenoh:// client URL with mutual TLS: the CA, and this client's certificate and key."""
    return (
        f"zenoh://?connect={endpoint}&mode=client&ca={pki / 'ca.pem'}"
        f"&cert={pki / f'{client}.pem'}&cert_key={pki / f'{client}.key'}"
    )


def _config(name: str, out: Path, extra: dict[str, object], url: str = URL) -> Path:
    doc = tomllib.loads((EXAMPLES / name).read_text())
    assert any(u.startswith("zenoh://") for u in doc["buses"].values()), name
    for bus, example in doc["buses"].items():
        if example.startswith("zenoh://"):
            doc["buses"][bus] = url  # the example's router address -> the one on this loopback
    path = out / name
    path.write_text(tomli_w.dumps(_merge(doc, extra)))
    return path


@pytest.mark.timeout(120)
@pytest.mark.parametrize("link", ["tcp", "mtls", "tls-users"])
def test_an_agent_on_zenoh_is_flown_by_an_operator_on_zenoh(
    netns: NetNamespace, tmp_path: Path, link: str
) -> None:
    router_log, agent_log = tmp_path / "router.log", tmp_path / "agent.log"
    router_args = ["--listen", f"tcp/127.0.0.1:{PORT}"]
    urls = {"agent": URL, "operator": URL}
    if link == "mtls":
        pki = lab_ca(tmp_path / "pki", "agent", "operator")
        endpoint = f"tls/127.0.0.1:{PORT}"
        router_args = ["--listen", endpoint, "--tls-cert", str(pki / "router.pem"),
                       "--tls-key", str(pki / "router.key"), "--ca", str(pki / "ca.pem")]  # fmt: skip
        urls = {who: mtls_url(pki, who, endpoint) for who in urls}
    elif link == "tls-users":  # TLS for privacy, a password per client (files, never in the config)
        pki = lab_ca(tmp_path / "pki")
        endpoint = f"tls/127.0.0.1:{PORT}"
        (tmp_path / "users.txt").write_text("agent:agent-secret-1\noperator:operator-secret-2\n")
        for who, secret in (("agent", "agent-secret-1"), ("operator", "operator-secret-2")):
            (tmp_path / f"{who}.auth").write_text(f"{who}:{secret}\n")
        router_args = ["--listen", endpoint, "--tls-cert", str(pki / "router.pem"),
                       "--tls-key", str(pki / "router.key"), "--users", str(tmp_path / "users.txt")]  # fmt: skip
        urls = {
            who: f"zenoh://?connect={endpoint}&mode=client&ca={pki / 'ca.pem'}&auth={tmp_path / f'{who}.auth'}"
            for who in urls
        }
    with open(router_log, "w") as rlog, open(agent_log, "w") as alog:
        netns.antalate(
            "router",
            *router_args,
            stdout=rlog,
            stderr=subprocess.STDOUT,
            cwd=str(REPO),
        )
        agent = _config(
            "agent_zenoh.toml",
            tmp_path,
            {
                "hlc": {"default_takeoff_altitude": 3.0, "autopilot_params": FAST_SIM},
                "security": {"swarm_key": KEY, "state_dir": str(tmp_path / "state")},
            },
            urls["agent"],
        )
        netns.antalate("agent", str(agent), stdout=alog, stderr=subprocess.STDOUT, cwd=str(REPO))
        operator = _config(
            "operator_remote.toml", tmp_path, {"security": {"swarm_key": KEY}}, urls["operator"]
        )
        op = OperatorClient(netns.peer("tests.lan.lan_operator", str(operator), "--stale-after", "2"))
        try:
            name = tomllib.loads(agent.read_text())["agent"]["name"]
            op.wait_all([name], "STANDBY", timeout=30)
            op.command("TAKEOFF", altitude=3.0)
            op.wait_all([name], "MISSION", timeout=30)
            op.command("RTL")
            op.wait_all([name], "STANDBY", timeout=40)
            status = op.wait(lambda s: s["pending"] == 0, timeout=10, what="no command pending")
            assert [c["status"] for c in status["commands"]] == ["acked", "acked"], status["commands"]
            assert status["agents"][name]["in_air"] is False
        finally:
            op.quit()
    assert "Traceback" not in agent_log.read_text()
    said = {"mtls": "(mutual TLS, keys under antalate only)", "tls-users": "(TLS, users file, keys under"}
    if link in said:
        assert said[link] in router_log.read_text()
