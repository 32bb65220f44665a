"""The transport registry: a bus URL's scheme alone picks its transport, an unknown or malformed URL is
refused with what was expected, and no module outside ``antalate_lcm/transports/`` reads a scheme from
a URL's text (issue 26)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from antalate_lcm.base.errors import AntalateError, BusUnavailable, InvalidBusUrl, UnknownTransport
from antalate_lcm.core.bus import Buses
from antalate_lcm.transports import TRANSPORTS, open_lcm, parse_lcm_url, transport_for
from antalate_lcm.transports.base import Transport
from antalate_lcm.transports.file import File
from antalate_lcm.transports.memq import Memq
from antalate_lcm.transports.tcpq import Tcpq
from antalate_lcm.transports.udpm import Mpudpm, Udpm
from antalate_lcm.transports.zenoh import ZENOH_NOT_LCM, Zenoh
from antalate_lcm.wire import security
from tests import REPO

#: One URL of each scheme, the transport it must get, and whether other hosts reach it.
CASES: list[tuple[str, type[Transport], bool]] = [
    ("udpm://239.255.76.67:7667?ttl=0", Udpm, True),
    ("udpm://", Udpm, True),
    ("mpudpm://239.255.76.67:7667?nports=4", Mpudpm, True),
    ("memq://", Memq, False),
    ("file:///tmp/flight.lcm?mode=r&speed=2", File, False),
    ("tcpq://127.0.0.1:7700", Tcpq, True),
    ("zenoh://swarm?connect=tcp/192.0.2.10:7447", Zenoh, True),
]


def test_the_registry_maps_each_scheme_to_its_own_transport() -> None:
    assert list(TRANSPORTS) == ["udpm", "mpudpm", "memq", "file", "tcpq", "zenoh"]
    assert all(cls.scheme == scheme for scheme, cls in TRANSPORTS.items())
    assert {cls for _, cls, _ in CASES} == set(TRANSPORTS.values())  # every transport is tried below


@pytest.mark.parametrize(("url", "cls", "reachable"), CASES)
def test_the_scheme_picks_the_transport(url: str, cls: type[Transport], reachable: bool) -> None:
    transport = transport_for(url)
    assert type(transport) is cls
    assert transport.url.url == url and transport.url.scheme == cls.scheme
    assert transport.network_reachable is reachable
    assert security.network_reachable(url) is reachable  # the exposure policy asks the transport
    # Only antalate's own transport is closed to the LCM tools; only memq stays in the process.
    assert transport.not_lcm == (ZENOH_NOT_LCM if cls is Zenoh else "")
    assert transport.in_process is (cls is Memq)
    # Only memq and a log file stay with their process (antalate run --processes refuses them).
    assert transport.crosses_processes is (cls not in (Memq, File))


def test_the_transport_keeps_parallel_runs_apart() -> None:
    """``antalate sweep --jobs``: udpm moves a slot's port (query kept), zenoh cannot keep runs apart,
    the others keep their URL."""
    udpm = transport_for("udpm://239.255.76.67:7667?ttl=0")
    assert udpm.for_slot(0, 100) == "udpm://239.255.76.67:7667?ttl=0"
    assert udpm.for_slot(2, 100) == "udpm://239.255.76.67:7867?ttl=0"
    assert transport_for("udpm://").for_slot(1, 100) == "udpm://239.255.76.67:7767"
    with pytest.raises(ValueError, match="no port for parallel slot 3"):
        transport_for("udpm://239.255.76.67:65500").for_slot(3, 100)
    with pytest.raises(ValueError, match="use --jobs 1"):
        transport_for("zenoh://swarm").for_slot(0, 100)
    for url in ("memq://", "tcpq://127.0.0.1:7700", "mpudpm://239.255.76.67:7667?nports=4"):
        assert transport_for(url).for_slot(1, 100) == url


def test_the_transport_fills_in_what_its_url_leaves_out() -> None:
    udpm = transport_for("udpm://").url
    assert (udpm.host, udpm.port) == ("239.255.76.67", 7667)
    tcpq = transport_for("tcpq://").url
    assert (tcpq.host, tcpq.port) == ("127.0.0.1", 7700)
    assert transport_for("zenoh://").url.network == "antalate"


@pytest.mark.parametrize(
    "url", ["http://239.255.76.67:7667", "UDPM://239.255.76.67:7667", "udp://", "lcm://x"]
)
def test_an_unknown_scheme_is_refused_naming_the_known_ones(url: str) -> None:
    with pytest.raises(UnknownTransport) as info:
        transport_for(url)
    err = info.value
    scheme = url.partition("://")[0]
    assert err.url == url
    assert f"not '{scheme}://'" in err.reason
    assert "udpm://, mpudpm://, memq://, file://, tcpq://, zenoh://" in err.reason
    # One root: the CLI and the console catch it as every other antalate error, a caller of the old
    # open path as a BusUnavailable, a validator as a ValueError.
    assert isinstance(err, BusUnavailable) and isinstance(err, AntalateError) and isinstance(err, ValueError)


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("239.255.76.67:7667", "an LCM URL provider://network?options"),
        ("://239.255.76.67:7667", "an LCM URL provider://network?options"),
        ("udpm://10.0.0.1:7667", "a multicast group (224.0.0.0/4); 10.0.0.1 is a unicast address"),
        ("udpm://239.255.76.67", "a port after the group"),
        ("udpm://239.255.76.67:99999", "a port 1-65535 after the group, not '99999'"),
        ("udpm://239.255.76.67:7667?ttl=300", "an integer 0-255"),
        ("udpm://239.255.76.67:7667?ttl=1&ttl=2", "option ttl once"),
        ("udpm://239.255.76.67:7667?transmit_only=true", "obsolete: liblcm ignores it"),
        ("mpudpm://239.255.76.67:65530?nports=10", "ports up to 65535"),
        ("memq://anything", "nothing after memq://"),
        ("file://", "the path of an LCM log after file://"),
        ("file:///x.lcm?mode=q", "r (read), w (write) or a (append)"),
        ("tcpq://not a host:7700", "a server HOST:PORT"),
        ("zenoh://?mode=client", "option connect with mode=client"),
        ("zenoh://?connect=tcp/192.0.2.1:0", "a port 1-65535 in option connect, not '0'"),
        ("zenoh://a*b", "a Zenoh key prefix after zenoh://"),
    ],
)
def test_a_malformed_url_is_refused_saying_what_was_expected(url: str, expected: str) -> None:
    with pytest.raises(InvalidBusUrl) as info:
        transport_for(url)
    assert not isinstance(info.value, UnknownTransport)
    assert info.value.reason.startswith("expected ") and expected in info.value.reason
    with pytest.raises(ValueError, match=re.escape(expected)):
        parse_lcm_url(url)  # what config files are checked with: the same words


def test_a_transport_refuses_another_schemes_url() -> None:
    """A transport class used directly (the udpm socket helpers) checks that the URL is its own."""
    with pytest.raises(ValueError, match="a udpm:// URL, not 'mpudpm://"):
        Udpm.parse("mpudpm://239.255.76.67:7667")


def test_the_bus_and_the_lcm_tools_ask_the_registry() -> None:
    """The bus opens a declared URL through its transport: an unknown scheme is the registry's error
    at open, before any node starts; the LCM tools' opener refuses antalate's own transport."""
    bus = Buses({"lan": "http://239.255.76.67:7667"})
    try:
        with pytest.raises(UnknownTransport, match="memq://"):
            bus.open()
    finally:
        bus.close()
    with pytest.raises(BusUnavailable, match="antalate bridge"):
        open_lcm("zenoh://?connect=tcp/127.0.0.1:7447")
    with pytest.raises(UnknownTransport):
        security.network_reachable("carrier-pigeon://loft")  # never guessed either way


# ------------------------------------------------------------------ no scheme read outside transports/

#: Modules that still read a scheme from a URL's text, left to their owners (issue 26); remove a line
#: when it asks the transport instead, never add one.
KNOWN_READERS: set[str] = set()


def _scheme_readings(source: str) -> list[int]:
    """Lines where a bus URL's scheme is read from its text: ``url.startswith("udpm://")``,
    ``url.split("://")``/``partition``, or a comparison with a bare scheme (``== "memq"``)."""
    schemes = set(TRANSPORTS)

    def is_scheme_prefix(node: ast.expr) -> bool:
        if isinstance(node, ast.Tuple):
            return any(is_scheme_prefix(e) for e in node.elts)
        return (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and node.value.partition("://")[0] in schemes
            and "://" in node.value
        )

    def is_scheme(node: ast.expr) -> bool:
        if isinstance(node, ast.Tuple | ast.List | ast.Set):
            return any(is_scheme(e) for e in node.elts)
        return isinstance(node, ast.Constant) and node.value in schemes

    tree = ast.parse(source)
    # A prefix kept in a name first (``_IN_PROCESS = ("memq://", "file://")``) counts as written there.
    named = {
        target.id: node.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Assign)
        for target in node.targets
        if isinstance(target, ast.Name)
    }
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            method = node.func.attr
            args = [named.get(a.id, a) if isinstance(a, ast.Name) else a for a in node.args]
            if (method in ("startswith", "endswith") and any(is_scheme_prefix(a) for a in args)) or (
                method in ("split", "rsplit", "partition", "rpartition")
                and args[:1]
                and isinstance(args[0], ast.Constant)
                and args[0].value == "://"
            ):
                lines.append(node.lineno)
        elif isinstance(node, ast.Compare) and any(is_scheme(c) for c in [node.left, *node.comparators]):
            lines.append(node.lineno)
    return sorted(set(lines))


def test_no_module_outside_transports_reads_a_url_scheme() -> None:
    """The registry is the one place a scheme is mapped to what it means."""
    found = {}
    for package in ("antalate_lcm", "operator_tui", "behaviors"):
        for path in sorted((REPO / package).rglob("*.py")):
            rel = path.relative_to(REPO).as_posix()
            if rel.startswith("antalate_lcm/transports/") or rel in KNOWN_READERS:
                continue
            lines = _scheme_readings(path.read_text())
            if lines:
                found[rel] = lines
    assert found == {}


def test_the_scheme_rule_sees_what_it_is_about() -> None:
    bad = [
        'if url.startswith("zenoh://"): pass',
        'if url.startswith(("memq://", "file://")): pass',
        'LOCAL = ("memq://", "file://")\nok = url.startswith(LOCAL)',
        'scheme = url.split("://", 1)[0]',
        'ok = url.split(":", 1)[0] == "memq"',
        'ok = scheme not in ("memq", "file")',
    ]
    good = [
        'url = "memq://"',
        'if self.url.startswith("http://"): pass',
        "ok = transport_for(url).network_reachable",
        'host, _, port = text.partition(":")',
    ]
    assert [bool(_scheme_readings(s)) for s in bad] == [True] * len(bad)
    assert [bool(_scheme_readings(s)) for s in good] == [False] * len(good)


def test_every_known_reader_still_reads_one() -> None:
    """A line of KNOWN_READERS goes once its module asks the transport."""
    assert all(_scheme_readings((REPO / rel).read_text()) for rel in KNOWN_READERS)
    assert all(Path(REPO / rel).exists() for rel in KNOWN_READERS)


def test_the_old_datagram_module_still_works_with_a_warning() -> None:
    """docs/lan.md told users to forge datagrams with antalate_lcm.lcm_datagram: one more release."""
    import importlib
    import sys

    from antalate_lcm.transports import datagram

    sys.modules.pop("antalate_lcm.lcm_datagram", None)
    with pytest.warns(DeprecationWarning, match="antalate_lcm.transports.datagram"):
        old = importlib.import_module("antalate_lcm.lcm_datagram")
    assert old.short_datagram is datagram.short_datagram and old.fragments is datagram.fragments
    assert old.Reassembler is datagram.Reassembler


def test_a_child_started_while_a_bus_opens_keeps_its_stderr(capfd: pytest.CaptureFixture[str]) -> None:
    """While liblcm's chatter is captured, fd 2 is a file: an agent process started by another thread
    then lost every line it wrote (a CI run's ``antalate run --processes 2`` printed none of its first
    process's lines). The spawn waits for the capture to end instead."""
    import sys
    import threading

    from antalate_lcm.runtime.agent import run_processes
    from antalate_lcm.transports import captured_stderr

    capturing, spawned = threading.Event(), threading.Event()

    def open_slowly() -> None:
        with captured_stderr():
            capturing.set()
            spawned.wait(1.0)  # the spawn below must not happen in here: it times out instead

    opener = threading.Thread(target=open_slowly)
    opener.start()
    assert capturing.wait(10)
    child = [sys.executable, "-c", "import sys; print('the child speaks', file=sys.stderr)"]

    def spawn() -> None:
        run_processes(lambda i, n: child, 1, grace=10)
        spawned.set()

    spawner = threading.Thread(target=spawn)
    spawner.start()
    spawner.join(30)
    opener.join(30)
    assert "the child speaks" in capfd.readouterr().err


def test_another_threads_lines_written_while_a_bus_opens_are_not_lost(
    monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """liblcm says nothing when it opens a bus; what fd 2 got meanwhile is another thread's, put back."""
    import os
    import threading

    import lcm

    real = lcm.LCM

    def opened_while_another_thread_logs(url: str) -> object:
        other = threading.Thread(target=os.write, args=(2, b"a warning of another thread\n"))
        other.start()
        other.join()
        return real(url)

    monkeypatch.setattr(lcm, "LCM", opened_while_another_thread_logs)
    open_lcm("memq://")
    assert "a warning of another thread" in capfd.readouterr().err
