"""Simulated time over several processes (``antalate run --speed --processes P``): one clock for all.

The grant rule (``runtime/time_grant.py``) is checked on its own; then real runs: the operator's
process and two ``antalate agent --shard`` processes, MC, HLC, BMA with ``dovrat_swarm`` and the
sim for 10 agents, with lossy broadcasts, a freeze and seeded packet losses, recorded and hashed
message by message (``tests/experiments/test_simtime.py`` does the same in one process); a run replayed gives
the same messages, another seed others; and a process killed mid-run stops the run in one message.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest

from antalate_lcm.cli import main
from antalate_lcm.core.executor import Executor
from antalate_lcm.core.simclock import SIM_START, SimClock
from antalate_lcm.runtime.experiment import Experiment, run
from antalate_lcm.runtime.replay import read_record
from antalate_lcm.runtime.script import load_script
from antalate_lcm.runtime.time_coordinator import (
    _FRAME,
    SimulatedBuses,
    TimeCoordinator,
    _frame,
    simulated_buses,
)
from antalate_lcm.runtime.time_grant import (
    Advance,
    Deliver,
    Interest,
    Report,
    add_interest,
    decide,
    decode_messages,
    encode_interest,
    encode_message,
    merge,
    pace,
    remaining,
    woken,
)
from tests.experiments.test_simtime import SCRIPT, config, message_hashes
from tests.harness.polling import wait_for
from tests.harness.process import antalate_argv

AGENTS = 10
PROCESSES = 2


# ----------------------------------------------------------------------------- the rule
def test_no_grant_while_a_process_still_works_or_has_not_joined() -> None:
    assert decide([Report(5.0), None, Report(3.0)]) is None
    assert decide([]) is None


def test_time_moves_to_the_earliest_next_timer_once_nothing_is_in_flight() -> None:
    decision = decide([Report(5.0), Report(3.25), Report(math.inf), Report(3.25)])
    # Only the processes with a timer then are woken; the others keep their reports.
    assert decision == Advance(3.25, (1, 3))
    assert remaining([Report(5.0), Report(3.25), Report(math.inf), Report(3.25)], decision) == [
        Report(5.0),
        None,
        Report(math.inf),
        None,
    ]
    # Nothing scheduled anywhere: nothing on simulated time can happen, so no grant.
    assert decide([Report(math.inf), Report(math.inf)]) is None


def test_messages_sent_now_reach_the_others_now_in_process_order() -> None:
    a, b = encode_message("lan", "A/X", b"1"), encode_message("lan", "B/X", b"22")
    c = encode_message("wan", "C/Y", b"")
    decision = decide([Report(1.0, a), Report(0.5, b + c), Report(2.0)])
    # Not an advance to 0.5, though that is the earliest timer: the messages are delivered first.
    assert decision == Deliver((b + c, a, a + b + c))
    assert woken(decision) == (0, 1, 2)
    # A process given nothing sleeps on, its report kept without the messages now handed on.
    alone = decide([Report(1.0, a), Report(0.5), Report(2.0)])
    assert alone == Deliver((b"", a, a)) and woken(alone) == (1, 2)
    assert remaining([Report(1.0, a), Report(0.5), Report(2.0)], alone) == [Report(1.0), None, None]
    assert list(decode_messages(a + b + c)) == [
        ("lan", "A/X", b"1"),
        ("lan", "B/X", b"22"),
        ("wan", "C/Y", b""),
    ]


def test_a_second_report_adds_its_messages_and_replaces_the_next_timer() -> None:
    first = Report(4.0, encode_message("lan", "A", b"x"))
    assert merge(None, first) == first
    assert merge(first, Report(2.0, encode_message("lan", "B", b"y"))) == Report(
        2.0, encode_message("lan", "A", b"x") + encode_message("lan", "B", b"y")
    )


def test_a_speed_paces_the_grants_and_max_never_waits() -> None:
    assert pace(math.inf, 0.0, 100.0, 1e6, 0.0) == 0.0
    assert pace(2.0, 10.0, 100.0, 104.0, 10.5) == pytest.approx(1.5)  # 4 s at 2x: 2 s from 10.0
    assert pace(2.0, 10.0, 100.0, 104.0, 13.0) == 0.0  # behind: at once


def test_only_the_buses_that_cross_processes_are_carried() -> None:
    buses = {
        "lan": "udpm://239.255.76.99:7699?ttl=0",
        "wan": "zenoh://",
        "mine": "memq://",
        "log": "file:///x",
    }
    simulated, crossing = simulated_buses(buses)
    assert crossing == ["lan", "wan"]
    # A memq:// URL of its own each (the bus keeps one link per URL): never the in-process bus's.
    assert simulated == {"lan": "memq://?", "wan": "memq://??", "mine": "memq://", "log": "file:///x"}


# ----------------------------------------------------------------------------- real runs
@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("simtime-processes")
    (d / "swarm.toml").write_text(config(2.0))
    (d / "script.toml").write_text(SCRIPT)
    (d / "long.toml").write_text("mission_time = 60.0\n")
    (d / "endless.toml").write_text("mission_time = 3600.0\n")
    return d


def fly(files: Path, seed: int, name: str, *, agents: int = AGENTS, script: str = "script.toml") -> Path:
    out = files / name
    outcome = run(
        Experiment(
            config_path=str(files / "swarm.toml"),
            agents=agents,
            processes=PROCESSES,
            script=load_script(files / script),
            output=str(out),
            force=True,
            speed=math.inf,
            seed=seed,
            log_level="WARNING",
            measure=False,
        )
    )
    assert outcome.code == 0, outcome.text()
    assert outcome.simulated_s is not None and outcome.simulated_s > 6.0
    return out


def test_processes_on_one_clock_give_the_same_messages_for_a_seed_and_others_for_another(
    files: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recorded = fly(files, 1, "seed1.lcm")
    first = message_hashes(recorded)
    assert len(first) > 2500  # 10 agents' states, telemetry, commands and the faults' records
    assert read_record(recorded)["processes"] == PROCESSES
    capsys.readouterr()
    # The replay flies it again over two processes (new ones, with their own hash seeds) and
    # compares every message.
    assert main(["replay", str(recorded)]) == 0
    assert "replay matches the recording" in capsys.readouterr().out

    other = message_hashes(fly(files, 2, "seed2.lcm"))
    assert other != first


def test_processes_on_one_clock_run_faster_than_real_time(files: Path) -> None:
    out = files / "long.lcm"
    outcome = run(
        Experiment(
            config_path=str(files / "swarm.toml"),
            agents=2,
            processes=PROCESSES,
            script=load_script(files / "long.toml"),
            output=str(out),
            force=True,
            speed=math.inf,
            seed=1,
            log_level="WARNING",
            measure=False,
        )
    )
    assert outcome.code == 0, outcome.text()
    # A 60 s mission and its take-off and return, over three processes, in less real time than
    # it covered (a few seconds on an idle machine: the margin is for a loaded one).
    assert outcome.simulated_s is not None and outcome.simulated_s > 60.0
    assert outcome.real_s < outcome.simulated_s, outcome.text()


def _children(pid: int) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry))
    return out


def _fly_then(
    files: Path, name: str, hurt: int, *extra: str
) -> tuple[subprocess.CompletedProcess[str], int, int]:
    """An endless 4-agent run over 2 processes at ``--speed max``; once it flies, signal ``hurt``
    to its second agent process. The run's outcome, that process (pid) and its index (1 or 2)."""
    out = files / f"{name}.lcm"
    argv = antalate_argv("--log-level", "WARNING", "run", str(files / "swarm.toml"))
    argv += [
        "--agents",
        "4",
        "--processes",
        str(PROCESSES),
        "--headless",
        "--script",
        str(files / "endless.toml"),
    ]
    argv += ["-o", str(out), "--speed", "max", "--seed", "1", *extra]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # Flying: both agent processes up, and the log growing (every process has joined the clock).
        children = wait_for(lambda: len(_children(proc.pid)) == PROCESSES and _children(proc.pid), timeout=60)
        assert children, "the agent processes never started"
        assert wait_for(lambda: out.exists() and out.stat().st_size > 200_000, timeout=60), (
            "the run never flew"
        )
        victim = max(children)  # the second agent process
        os.kill(victim, hurt)
        text, _ = proc.communicate(timeout=120)  # a hang fails here
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    done = subprocess.CompletedProcess(argv, proc.returncode, text)
    return done, victim, 1 + sorted(children).index(victim)


def test_a_process_killed_mid_run_stops_the_run_with_one_clear_message(files: Path) -> None:
    done, _victim, index = _fly_then(files, "killed", signal.SIGKILL)
    text = done.stdout
    assert done.returncode == 1, text
    assert "FAILED" in text and "(it died, or was killed)" in text, text
    assert f"agent process {index} of 2 left the simulated clock at" in text, text


def test_a_hung_process_is_named_and_killed_and_the_others_stop(files: Path) -> None:
    """A process that stops answering (SIGSTOP: as a behavior stuck in an endless loop) held every
    other process for ever; after --stall-timeout the run says which one, stops, and kills it."""
    began = time.monotonic()
    done, victim, index = _fly_then(files, "hung", signal.SIGSTOP, "--stall-timeout", "3")
    text = done.stdout
    assert done.returncode == 1, text
    assert "FAILED" in text, text
    assert f"agent process {index} of 2 (pid {victim}) sent nothing for 3 s of real time at" in text, text
    assert "it hangs or was stopped" in text, text
    assert not Path(f"/proc/{victim}").exists(), "the hung process was left behind"
    # Stopped by the watchdog, not by the 60 s grace for a process that ignores SIGINT.
    assert time.monotonic() - began < 100, text


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "soon"])
def test_a_stall_timeout_that_cannot_end_a_hang_is_refused(
    value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["run", "swarm.toml", "--stall-timeout", value])
    assert exit_.value.code == 2
    assert f"--stall-timeout: a number of seconds > 0, got {value!r}" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (
            ["--shard", "0/2", "--sim-clock", "/nonexistent/clock"],
            "cannot join the simulated clock at /nonexistent",
        ),
        (["--sim-clock", "/nonexistent/clock"], "--sim-clock is for the agent processes of `antalate run`"),
    ],
)
def test_an_agent_process_without_its_clock_says_so_in_one_line(
    files: Path, argv: list[str], words: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["agent", str(files / "swarm.toml"), *argv]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


def test_a_process_is_handed_only_what_it_subscribes_to() -> None:
    mc, tel = encode_message("lan", "a-01/MC_STATE", b"s"), encode_message("lan", "a-01/TELEMETRY", b"t")
    cmd = encode_message("lan", "SWARM_OPERATOR_CMD", b"c")
    recorder, agents, quiet = Interest(), Interest(), Interest()
    add_interest(recorder, encode_interest([("lan", ".*", True)]))
    add_interest(
        agents, encode_interest([("lan", "SWARM_OPERATOR_CMD", False), ("lan", "b-.*/TELEMETRY", True)])
    )
    # The agents' process does not want another's MC state or telemetry, the recorder wants all.
    decision = decide([Report(1.0, cmd), Report(1.0, mc + tel), Report(1.0)], [recorder, agents, quiet])
    assert decision == Deliver((mc + tel, cmd, b""))
    # Messages nobody else wants are no round of their own: time moves on.
    assert decide([Report(1.0), Report(1.0, mc + tel), Report(2.0)], [quiet, quiet, agents]) == Advance(
        1.0, (0, 1)
    )


def test_a_speed_bounds_the_shared_clock(files: Path) -> None:
    outcome = run(
        Experiment(
            config_path=str(files / "swarm.toml"),
            agents=2,
            processes=PROCESSES,
            script=load_script(files / "long.toml").model_copy(update={"mission_time": 4.0}),
            output=str(files / "paced.lcm"),
            force=True,
            speed=4.0,
            seed=1,
            log_level="WARNING",
            measure=False,
        )
    )
    assert outcome.code == 0, outcome.text()
    # Never faster than 4x real time (a lower bound: a loaded machine only makes it slower; the
    # same flight at max takes about a second).
    assert outcome.simulated_s is not None and outcome.real_s >= outcome.simulated_s / 4.0


def _recv_frame(sock: socket.socket) -> tuple[bytes, int, float, bytes]:
    sock.settimeout(30)
    head = b""
    while len(head) < _FRAME.size:
        head += sock.recv(_FRAME.size - len(head))
    kind, round_, value, size = _FRAME.unpack(head)
    payload = b""
    while len(payload) < size:
        payload += sock.recv(size - len(payload))
    return kind, round_, value, payload


def test_the_coordinator_hears_a_process_whose_subscriptions_take_several_reads() -> None:
    """A thousand agents' subscriptions are more than one read of the socket: lost, the agents
    never heard the operator (what a 1,000-agent run over two processes did)."""
    clock = SimClock()
    executor = Executor(sim=clock)
    bus = SimulatedBuses({"lan": "memq://?"}, ["lan"])
    bus.attach(executor)
    coordinator = TimeCoordinator(2)
    coordinator.serve(clock, bus, executor, ["lan"])

    def operator() -> None:  # this process's timer, 1 s in: a message the agent wants, one not
        bus.publish("lan", "agent-19999/OPERATOR_CMD", b"take off")
        bus.publish("lan", "agent-19999/MC_STATE", b"not wanted")

    executor.call_later(1.0, operator)
    executor.start()
    agent = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        agent.connect(coordinator.address)
        agent.sendall(_frame(b"H", 0, 1.0))
        wanted = [("lan", f"agent-{i:05d}/OPERATOR_CMD", False) for i in range(20_000)]
        interest = _frame(b"I", 0, 0.0, encode_interest(wanted))
        assert len(interest) > 500_000
        agent.sendall(interest)
        time.sleep(0.2)  # the coordinator reads it all, over several reads, before the report comes
        agent.sendall(_frame(b"R", 0, SIM_START + 1.0))
        kind, round_, t, _ = _recv_frame(agent)
        assert kind == b"A" and t == SIM_START + 1.0  # both timers are due then
        agent.sendall(_frame(b"R", round_, SIM_START + 2.0))
        kind, _, t, payload = _recv_frame(agent)
        assert kind == b"D" and t == SIM_START + 1.0
        assert list(decode_messages(payload)) == [("lan", "agent-19999/OPERATOR_CMD", b"take off")]
    finally:
        agent.close()
        executor.stop()
        coordinator.close()
