"""An outsider and a witness on the WAN path (issue 29), run inside the test's network namespace.

It holds no key and no certificate: a plain Zenoh client of the router and raw UDP sockets on the
sites' LANs, which is all the attacks of tests/security/test_wan_*.py need. As a witness it sends
fresh probes one way and times their arrival the other way, and counts the bytes each LAN and the
Zenoh side carried.

Requests, one JSON object a line, one JSON reply line each (``{"ok": bool, ...}``):

``zput``      {key, hex, att?}: a Zenoh put on any key, with any attachment (hex)
``token``     {key}: declare a liveliness token and keep it; ``untoken`` {key}: undeclare it
``keys``      {selector}: the liveliness tokens a query lists
``lan``       {lan, hexes, gap?}: send raw datagrams to a LAN's group
``probe``     {src, dst, timeout}: a fresh message from ``src`` (a LAN or "zenoh"), its arrival at ``dst``
``flood``     {lan, n, prefix}: ``n`` short datagrams on as many new channels, in the background;
              ``flood_wait``: until they are sent
``mark``      start counting bytes again; ``bytes``: datagram and sample bytes seen since ``mark``
"""

from __future__ import annotations

import json
import secrets
import socket
import sys
import threading
import time
from typing import Any

import zenoh

from antalate_lcm.transports.datagram import Reassembler, short_datagram
from antalate_lcm.transports.udpm import udpm_socket
from tests.harness.jsonl import serve

LANS = {"a": ("239.255.76.67", 7667), "b": ("239.255.76.69", 7669), "c": ("239.255.76.71", 7671)}
PROBE = "probe/WAN"


class Witness:
    def __init__(self, router: str) -> None:
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", json.dumps([router]))
        config.insert_json5("scouting/multicast/enabled", "false")
        deadline = time.monotonic() + 30
        while True:  # the router process may still be starting
            try:
                self.session = zenoh.open(config)
                break
            except zenoh.ZError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        self.tokens: dict[str, Any] = {}
        self.flooding = threading.Thread()
        self.lock = threading.Lock()
        self.arrived: dict[bytes, float] = {}
        self.lan_bytes = {name: 0 for name in LANS}
        self.zenoh_bytes = 0
        self.zenoh_distinct: set[bytes] = (
            set()
        )  # payloads seen since mark (a second bridge's copy is not new)
        self.send = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.send.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
        self.sub = self.session.declare_subscriber("antalate/**", self._on_sample)
        for name, (group, port) in LANS.items():
            sock = udpm_socket(f"udpm://{group}:{port}?ttl=0")
            sock.setblocking(True)
            threading.Thread(target=self._read_lan, args=(name, sock), daemon=True).start()

    def _seen(self, data: bytes) -> None:
        with self.lock:
            self.arrived.setdefault(data, time.monotonic())

    def _on_sample(self, sample: Any) -> None:
        data = sample.payload.to_bytes()
        with self.lock:
            self.zenoh_bytes += len(data)
            self.zenoh_distinct.add(data)
        self._seen(b"zenoh" + data)

    def _read_lan(self, name: str, sock: socket.socket) -> None:
        reassembler = Reassembler()
        while True:
            datagram, sender = sock.recvfrom(65_535)
            with self.lock:
                self.lan_bytes[name] += len(datagram)
            message = reassembler.feed(datagram, sender)
            if message is not None and message[0] == PROBE:
                self._seen(name.encode() + message[1])

    def _flood(self, lan: str, n: int, prefix: str) -> None:
        group = LANS[lan]
        for i in range(n):
            self.send.sendto(short_datagram(f"{prefix}{i}/X", secrets.token_bytes(40)), group)
            if i % 100 == 99:
                time.sleep(0.002)  # ~40k datagrams/s: what one host sends, within the receivers' buffers

    def handle(self, req: dict[str, Any]) -> dict[str, Any]:
        op = req["op"]
        if op == "zput":
            att = bytes.fromhex(req["att"]) if req.get("att") is not None else None
            self.session.put(req["key"], bytes.fromhex(req["hex"]), attachment=att)
            return {"ok": True}
        if op == "token":
            self.tokens[req["key"]] = self.session.liveliness().declare_token(req["key"])
            return {"ok": True}
        if op == "untoken":
            self.tokens.pop(req["key"]).undeclare()
            return {"ok": True}
        if op == "keys":
            replies = self.session.liveliness().get(req["selector"], timeout=3.0)
            return {"ok": True, "keys": sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)}
        if op == "lan":
            group = LANS[req["lan"]]
            for h in req["hexes"]:
                self.send.sendto(bytes.fromhex(h), group)
                if req.get("gap"):
                    time.sleep(req["gap"])
            return {"ok": True}
        if op == "flood":  # in the background: the test probes the other direction meanwhile
            self.flooding = threading.Thread(target=self._flood, args=(req["lan"], req["n"], req["prefix"]))
            self.flooding.start()
            return {"ok": True}
        if op == "flood_wait":
            self.flooding.join()
            return {"ok": True}
        if op == "probe":
            payload = secrets.token_bytes(24)
            t0 = time.monotonic()
            if req["src"] == "zenoh":
                self.session.put(f"antalate/{PROBE}", payload)
            else:
                self.send.sendto(short_datagram(PROBE, payload), LANS[req["src"]])
            key = req["dst"].encode() + payload
            deadline = t0 + req["timeout"]
            while time.monotonic() < deadline:
                with self.lock:
                    t = self.arrived.get(key)
                if t is not None:
                    return {"ok": True, "latency": t - t0}
                time.sleep(0.002)
            return {"ok": True, "latency": None}
        if op == "mark":
            with self.lock:
                self.lan_bytes = dict.fromkeys(LANS, 0)
                self.zenoh_bytes = 0
                self.zenoh_distinct = set()
            return {"ok": True}
        if op == "bytes":
            with self.lock:
                distinct = sum(len(d) for d in self.zenoh_distinct)
                return {
                    "ok": True,
                    "lan": dict(self.lan_bytes),
                    "zenoh": self.zenoh_bytes,
                    "zenoh_distinct": distinct,
                }
        return {"ok": False, "error": f"unknown op {op!r}"}


def main() -> None:
    serve(Witness(sys.argv[1]).handle)


if __name__ == "__main__":
    main()
