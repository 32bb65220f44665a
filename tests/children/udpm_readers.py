"""Two of antalate's own udpm readers, liblcm's receive thread and a reader of another group, all on one
port: liblcm's datagrams (small and fragmented) reach them intact, the Bus's reach a plain liblcm
subscriber, hostile datagrams from a plain socket kill nobody, and closing the buses closes their sockets.
Prints one JSON object of findings (tests/transport/test_udpm_reader.py judges them).

    python -m tests.children.udpm_readers GROUP_A_URL GROUP_B_URL
"""

from __future__ import annotations

import json
import os
import socket
import struct
import sys
import time
from collections.abc import Callable
from typing import Any

import lcm

from antalate_lcm.core.bus import Buses
from antalate_lcm.msgs import telemetry_t
from antalate_lcm.transports.datagram import fragments, short_datagram


def until(cond: Callable[[], bool], timeout: float = 5.0) -> bool:
    end = time.time() + timeout
    while not cond() and time.time() < end:
        time.sleep(0.01)
    return cond()


def sockets() -> set[str]:
    """What this process's descriptors point at (``socket:[inode]`` for a socket)."""
    return {
        os.readlink(f"/proc/self/fd/{fd}")
        for fd in os.listdir("/proc/self/fd")
        if os.path.exists(f"/proc/self/fd/{fd}")
    }


def main(A: str, B: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    own, other = Buses({"a": A}), Buses({"a": A})  # two own readers on one port (SO_REUSEADDR)
    old = Buses({"a": A}, own_udpm_reader=False)  # liblcm's receive thread, beside them
    elsewhere = Buses({"b": B})  # the same port, another group
    got: dict[str, list[Any]] = {k: [] for k in ("exact", "regex", "other", "old", "elsewhere", "typed")}
    own.subscribe("a", "BIG", None, lambda ch, d: got["exact"].append(d))
    own.subscribe("a", "B.*", None, lambda ch, d: got["regex"].append((ch, d)), regex=True)
    own.subscribe("a", "uav1/TELEMETRY", telemetry_t, lambda ch, m: got["typed"].append(m.header.seq))
    other.subscribe("a", "BIG", None, lambda ch, d: got["other"].append(d))
    old.subscribe("a", "BIG", None, lambda ch, d: got["old"].append(d))
    elsewhere.subscribe("b", "BIG", None, lambda ch, d: got["elsewhere"].append(d))

    # liblcm sends: a small message and one it must fragment (300 kB)
    small, big = b"s" * 100, bytes(range(256)) * 1200
    lc = lcm.LCM(A)
    time.sleep(0.2)
    lc.publish("BIG", small)
    lc.publish("BIG", big)
    out["liblcm_to_own"] = until(
        lambda: len(got["exact"]) == 2 and len(got["other"]) == 2 and bool(got["old"])
    )
    out["exact_intact"] = got["exact"] == [small, big] and got["other"] == [small, big]
    # liblcm's own socket asks for no buffer: a 300 kB burst of fragments may overflow the kernel's
    # default (the own reader asks for 4 MiB, docs/lan.md); the small message it must have
    out["old_small"] = got["old"][:1] == [small]
    out["regex_intact"] = got["regex"] == [("BIG", small), ("BIG", big)]

    # the Bus sends (through liblcm): a plain liblcm subscriber receives it
    heard: list[int] = []
    lc.subscribe(
        "uav1/TELEMETRY", lambda ch, d: heard.append(telemetry_t.decode(d).header.seq)
    ).set_queue_capacity(1000)
    for seq in range(1, 51):
        m = telemetry_t()
        m.header.seq = seq
        own.publish("a", "uav1/TELEMETRY", m)
    end = time.time() + 5
    while len(heard) < 50 and time.time() < end:
        lc.handle_timeout(50)
    out["own_to_liblcm"] = heard
    out["own_hears_itself"] = until(lambda: got["typed"] == list(range(1, 51)))

    # hostile datagrams from a plain socket
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
    group = ("239.255.76.67", 7667)
    hostile = [
        b"",
        b"garbage",
        b"\xff" * 400,
        struct.pack(">II", 0x4C433032, 1),  # LC02 header only
        struct.pack(">II", 0x4C433032, 2) + b"BIG",  # no NUL
        short_datagram("C" * 64, b"x"),  # channel over 63 bytes
        struct.pack(">II", 0x4C433033, 3) + b"\0" * 8,  # truncated LC03 header
        struct.pack(">IIIIHH", 0x4C433033, 4, 100, 90, 1, 2) + b"x" * 50,  # past its message
        struct.pack(">IIIIHH", 0x4C433033, 5, 1 << 29, 0, 0, 2) + b"BIG\0x",  # over 256 MiB
    ]
    for d in hostile:
        s.sendto(d, group)
    for d in fragments("BIG", b"f" * 3000, seqno=77, size=1000):  # our builder, as liblcm lays it out
        s.sendto(d, group)
    s.sendto(short_datagram("BIG", b"after"), group)
    out["alive_after_hostile"] = until(
        lambda: got["exact"][-1:] == [b"after"] and got["old"][-1:] == [b"after"]
    )
    out["lens"] = {k: len(v) for k, v in got.items()}
    out["forged_fragments_reassembled_by_both"] = b"f" * 3000 in got["exact"] and b"f" * 3000 in got["old"]
    out["damaged"] = own.damaged_datagrams()
    out["elsewhere"] = len(got["elsewhere"])

    mine = set()
    for b in (own, other, elsewhere):
        for link in b._connections.values():
            assert link._receiver is not None, "a bus with the own reader has its receiver"
            mine.add(f"socket:[{os.fstat(link._receiver.fileno()).st_ino}]")
    out["open_before_close"] = len(mine & sockets())
    for b in (own, other, old, elsewhere):
        b.close()
    s.close()
    out["open_after_close"] = len(mine & sockets())
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], sys.argv[2])), flush=True)
