"""antalate's own udpm reader against liblcm on real multicast, in a private network namespace:
what either sends the other receives (fragmented messages included), hostile datagrams are dropped
and counted, the socket shares the port and is released on close, and another group is not heard."""

from __future__ import annotations

import json
import subprocess

from tests.harness.netns import NetNamespace

GROUP_A = "udpm://239.255.76.67:7667?ttl=0"
GROUP_B = "udpm://239.255.76.99:7667?ttl=0"


def test_own_reader_and_liblcm_on_one_group(netns: NetNamespace) -> None:
    proc = netns.python(
        "-m", "tests.children.udpm_readers", GROUP_A, GROUP_B, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    r = json.loads(out.strip().splitlines()[-1])
    assert r["liblcm_to_own"] and r["exact_intact"], r  # small and liblcm-fragmented, to both readers
    assert r["old_small"], r
    assert r["regex_intact"], r
    assert r["own_to_liblcm"] == list(range(1, 51)) and r["own_hears_itself"], r
    assert r["alive_after_hostile"], (r, err)
    assert r["forged_fragments_reassembled_by_both"], r  # our fragment layout is liblcm's
    assert r["damaged"] == 9, r  # every hostile datagram counted, once
    assert "not LCM or are damaged" in err  # and said, at a limited rate
    assert r["elsewhere"] == 0, r  # bound to its group, as liblcm binds
    assert r["open_before_close"] == 3 and r["open_after_close"] == 0, r  # Buses.close() closes its socket


#: A liblcm listener in a process of its own (argv: URL, channel, count): prints "ready", then the
#: messages it heard, as a JSON list of strings, once it has ``count`` or 10 s have passed.
_LISTENER = r"""
import json, sys, time
import lcm
lc = lcm.LCM(sys.argv[1])
heard = []
lc.subscribe(sys.argv[2], lambda ch, d: heard.append(d.decode())).set_queue_capacity(10000)
print("ready", flush=True)
end = time.time() + 10
while len(heard) < int(sys.argv[3]) and time.time() < end:
    lc.handle_timeout(50)
print(json.dumps(heard), flush=True)
"""

_OWN_SCRIPT = r"""
import json, os, socket, struct, subprocess, sys, time
import lcm
from pathlib import Path
from antalate_lcm.core.bus import Buses
from antalate_lcm.transports.datagram import short_datagram

A = sys.argv[1]
out = {}

def until(cond, timeout=5.0):
    end = time.time() + timeout
    while not cond() and time.time() < end:
        time.sleep(0.01)
    return cond()

def drops(bus):
    ino = os.fstat(next(iter(bus._connections.values()))._receiver.fileno()).st_ino
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        f = line.split()
        if int(f[9]) == ino:
            return int(f[12])
    return -1

own, peer = Buses({"a": A}), Buses({"a": A})
got = {"in": [], "out": [], "peer": []}
own.subscribe("a", "IN", None, lambda ch, d: got["in"].append(d))
peer.subscribe("a", "OUT", None, lambda ch, d: got["peer"].append(d))
heard = []
lc = lcm.LCM(A)
lc.subscribe("OUT", lambda ch, d: heard.append(d)).set_queue_capacity(1000)
# another process on the host, as lcm-spy or lcm-logger: a liblcm instance of its own
other = subprocess.Popen([sys.executable, "-c", LISTENER, A, "OUT", "20"], stdout=subprocess.PIPE, text=True)
assert other.stdout.readline().strip() == "ready"
time.sleep(0.2)
before = drops(own)
for i in range(20):
    own.publish("a", "OUT", b"o%d" % i)
end = time.time() + 5
while len(heard) < 20 and time.time() < end:
    lc.handle_timeout(50)
out["liblcm_hears_all"] = heard == [b"o%d" % i for i in range(20)]
out["another_bus_of_the_process_hears_all"] = until(lambda: len(got["peer"]) == 20)
out["another_process_hears_all"] = json.loads(other.communicate(timeout=20)[0]) == [f"o{i}" for i in range(20)]
# the own socket's copies went no further than its filter (the kernel counts them as dropped)
out["own_copies_dropped_in_the_kernel"] = until(lambda: drops(own) - before == 20)
peer.publish("a", "IN", b"from peer")
lc.publish("IN", b"from liblcm")
out["others_heard"] = until(lambda: got["in"] == [b"from peer", b"from liblcm"])
# another process's channels whose last part nobody here subscribes to: dropped in the kernel too
before = drops(own)
for i in range(10):
    peer.publish("a", "b-9/TELEMETRY", b"t%d" % i)
out["other_topics_dropped_in_the_kernel"] = until(lambda: drops(own) - before == 10)
# a channel with a subscribed last part passes the filter and is dropped by channel; a datagram
# the filter cannot read (an LC02 header and nothing more) goes; reception carries on after both
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
s.sendto(short_datagram("x/IN", b"not mine"), ("239.255.76.67", 7667))
s.sendto(struct.pack(">II", 0x4C433032, 9), ("239.255.76.67", 7667))
s.sendto(short_datagram("IN", b"after"), ("239.255.76.67", 7667))
out["hears_after_hostile"] = until(lambda: got["in"][2:] == [b"after"])
s.close()
# a subscriber of a channel the process publishes: its own messages are heard again
own.subscribe("a", "OUT", None, lambda ch, d: got["out"].append(d))
own.publish("a", "OUT", b"mine")
out["own_heard_once_subscribed"] = until(lambda: got["out"] == [b"mine"])
big = bytes(70_000)  # too large for one datagram: liblcm's fragmenting publish, heard as before
own.publish("a", "OUT", big)
out["fragmented_heard"] = until(lambda: got["out"][-1:] == [big])
for b in (own, peer):
    b.close()
print(json.dumps(out), flush=True)
"""


def test_a_process_drops_its_own_datagrams_until_it_subscribes_to_them(netns: NetNamespace) -> None:
    """The own sender's datagrams loop back to the own socket: dropped in the kernel while no
    subscription of the bus wants them, heard by everyone else, and heard again (for good) once the
    process subscribes to a channel it publishes on. Other processes' channels whose last part no
    subscription has are dropped in the kernel as well; a damaged datagram does not stop reception."""
    proc = netns.python(
        "-c",
        f"LISTENER = {_LISTENER!r}\n{_OWN_SCRIPT}",
        GROUP_A,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    r = json.loads(out.strip().splitlines()[-1])
    assert all(r.values()), r


_REFUSED_SCRIPT = r"""
import json, logging, socket, sys, time
from antalate_lcm.core.bus import Buses

logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(levelname)s %(name)s %(message)s")
A = sys.argv[1]

def until(cond, timeout=5.0):
    end = time.time() + timeout
    while not cond() and time.time() < end:
        time.sleep(0.01)
    return cond()

own, peer = Buses({"a": A}), Buses({"a": A})
conn = own._connection("a")
conn._receiver = conn._open_receiver()
# SO_LOCK_FILTER (asm-generic/socket.h): the kernel now refuses to attach a filter to this socket
conn._receiver.sock.setsockopt(socket.SOL_SOCKET, 44, 1)
got = {"in": [], "peer": []}
own.subscribe("a", "IN", None, lambda ch, d: got["in"].append(d))
own.subscribe("a", "IN2", None, lambda ch, d: got["in"].append(d))
peer.subscribe("a", "OUT", None, lambda ch, d: got["peer"].append(d))
time.sleep(0.2)
for i in range(5):
    own.publish("a", "OUT", b"o%d" % i)
    own.publish("a", "x/IN", b"not a subscribed channel")
peer.publish("a", "IN", b"from peer")
peer.publish("a", "IN2", b"from peer 2")
out = {
    "others_heard": until(lambda: got["in"] == [b"from peer", b"from peer 2"]),
    "peer_heard_all": until(lambda: len(got["peer"]) == 5),
}
time.sleep(0.2)
out["own_not_delivered"] = got["in"] == [b"from peer", b"from peer 2"]
out["unfiltered"] = conn._receiver.unfiltered and conn._receiver.applied == (None, None)
for b in (own, peer):
    b.close()
print(json.dumps(out), flush=True)
"""


def test_a_socket_that_refuses_a_filter_is_read_in_full(netns: NetNamespace) -> None:
    """Where the kernel will not attach the socket filter (here a filter lock, SO_LOCK_FILTER), the
    bus says so once in a log line and reads every datagram: the process's own and other channels'
    are dropped by channel, everyone else's are delivered, and nothing is raised."""
    proc = netns.python("-c", _REFUSED_SCRIPT, GROUP_A, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    r = json.loads(out.strip().splitlines()[-1])
    assert all(r.values()), (r, err)
    said = [line for line in err.splitlines() if "cannot filter datagrams" in line]
    assert len(said) == 1 and said[0].startswith("INFO antalate.bus"), err
    assert "Traceback" not in err, err


_OPTMEM_SCRIPT = r"""
import json, logging, sys, time
from antalate_lcm.core.bus import Buses

logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(levelname)s %(name)s %(message)s")
A = sys.argv[1]
# The socket option memory a filter is charged to (per namespace): one topic's filter fits, ten do not.
with open("/proc/sys/net/core/optmem_max", "w") as f:
    f.write("32768")

def until(cond, timeout=5.0):
    end = time.time() + timeout
    while not cond() and time.time() < end:
        time.sleep(0.01)
    return cond()

own, peer = Buses({"a": A}), Buses({"a": A})
conn = own._connection("a")
got = {}
def keep(ch, d):
    got.setdefault(ch, []).append(d)
own.subscribe("a", "IN", None, keep)
own.publish("a", "OUT", b"opens the sender: its own datagrams are filtered from now on")
time.sleep(0.1)
narrow = conn._receiver.applied[1]
late = [f"TOPIC_{i}" for i in range(9)]
for channel in late:
    own.subscribe("a", channel, None, keep)
time.sleep(0.2)
for channel in ["IN", *late]:
    peer.publish("a", channel, b"from peer")
for i in range(5):
    own.publish("a", "OUT", b"own: the kernel drops it")
out = {
    "a topic filter was attached first": narrow == frozenset({"IN"}),
    "every channel heard": until(lambda: all(got.get(c) == [b"from peer"] for c in ["IN", *late])),
    "own only now": conn._receiver.applied == (conn._sender.address, None) and not conn._receiver.unfiltered,
}
time.sleep(0.2)
out["nothing twice"] = all(len(v) == 1 for v in got.values()) and sorted(got) == sorted(["IN", *late])
for b in (own, peer):
    b.close()
print(json.dumps(out), flush=True)
"""


def test_a_topic_filter_too_large_for_the_socket_falls_back_to_the_own_datagrams(netns: NetNamespace) -> None:
    """A filter by topics can outgrow the socket's option memory (``net.core.optmem_max``: ENOMEM; a
    vehicle's BMA in the LAN test met it). The bus then filters only its own datagrams, says so once,
    and never leaves the earlier, narrower filter on the socket: that one dropped, in the kernel, the
    channels subscribed after it (the LAN test's cut-off vehicle heard no direction and did not move)."""
    proc = netns.python("-c", _OPTMEM_SCRIPT, GROUP_A, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    r = json.loads(out.strip().splitlines()[-1])
    assert all(r.values()), (r, err)
    said = [line for line in err.splitlines() if "cannot filter datagrams" in line]
    assert len(said) == 1 and "by topic" in said[0] and said[0].startswith("INFO antalate.bus"), err
    assert "Traceback" not in err, err
