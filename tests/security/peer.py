"""A peer on the swarm's network, run inside the test's network namespace and driven by JSON lines.

Two roles, one program, so each role is a separate process with only what it should know:

* the **attacker** (no ``--key``): records every datagram on the multicast group, publishes forged,
  truncated or replayed raw bytes, and speaks raw HTTP to the station. It cannot sign anything.
* the **operator** (``--key K``): the legitimate keyed operator the tests fly the swarm with, and a
  witness that tells genuine (correctly signed) messages from spoofed ones.

Requests, one JSON object a line, one JSON reply line each (``{"ok": bool, ...}``):

``publish``  {channel, type, fields, sign?, count?}: encode and send (``sign`` needs ``--key``)
``raw``      {channel, hex, count?}: send bytes as they are
``batch``    {items: [{channel, hex}], gap?}: send many datagrams (``gap`` s apart)
``replay``   {channel (regex), type, where, pick: "first"|"last", since?}: resend the recorded bytes of a
             matching message unchanged (what a replay attacker does); replies with the message
``capture``  like ``replay`` without sending: the recorded bytes (``hex``), for an attacker to edit
``wait``     {channel, type, where, timeout, since?, genuine?}: the first matching message
``history``  {channel, type, since?, genuine?}: every matching message
``mark``     the index of the next datagram (a "since" for later requests)
``udp_open``, ``udp_send`` {host, port, hexes, gap?}, ``udp_recv`` {since?}: raw UDP (MAVLink)
``sniff_start`` {port}, ``sniff_take``: TCP payloads to/from ``port`` seen on lo (a packet socket)
``http``     {method, url, json?, content?, headers?, bodies?, source?}: one request, or one per entry of ``bodies``
             (a flood); replies with ``responses: [{status, body}]``
"""

from __future__ import annotations

import re
import socket
import ssl
import threading
import time
from typing import Any

import httpx
import lcm

from antalate_lcm.wire.security import sign, verify
from antalate_lcm.wire.topics import MESSAGE_TYPES
from tests.children.probe import matches, to_dict
from tests.harness.jsonl import serve


def fill(msg: Any, fields: dict[str, Any]) -> Any:
    """Set fields from JSON: nested structs as objects, byte fields as hex strings."""
    for key, value in fields.items():
        current = getattr(msg, key)
        if isinstance(value, dict) and hasattr(current, "__slots__"):
            fill(current, value)
        elif isinstance(current, bytes) and isinstance(value, str):
            setattr(msg, key, bytes.fromhex(value))
        else:
            setattr(msg, key, value)
    return msg


class Peer:
    def __init__(
        self,
        urls: list[str],
        key: str | None,
        window: float,
        source: str | None = None,
        ca: str | None = None,
    ) -> None:
        # Every bus the swarm uses (the LAN group and the agents' "local" ttl=0 group): on one host,
        # or on a LAN where the attacker sends with a larger ttl, both reach the agents' sockets.
        self.buses = [lcm.LCM(url) for url in urls]
        self.key = key
        self.window = window
        self.seen: list[tuple[float, str, bytes]] = []
        self.udp: socket.socket | None = None
        self.udp_seen: list[bytes] = []
        self.cond = threading.Condition()
        for lc in self.buses:
            lc.subscribe(".*", self._on_msg).set_queue_capacity(1_000_000)
            threading.Thread(target=self._loop, args=(lc,), daemon=True).start()
        # ``source``: the address HTTP requests come from (the attacker is another host than the agents).
        # ``ca``: the operator verifies the station's certificate; the attacker verifies nothing.
        self.verify: Any = ssl.create_default_context(cafile=ca) if ca else False
        self.http = self._client(source)
        self._clients: dict[str, httpx.Client] = {}
        self.sniffed: list[bytes] = []

    def _on_msg(self, channel: str, data: bytes) -> None:
        with self.cond:
            self.seen.append((time.time(), channel, data))
            self.cond.notify_all()

    def _client(self, source: str | None) -> httpx.Client:
        transport = httpx.HTTPTransport(local_address=source, verify=self.verify) if source else None
        return httpx.Client(timeout=10.0, transport=transport, verify=self.verify)

    def _sniff(self, sock: socket.socket, port: int) -> None:
        """Keep the TCP payload of every IPv4 frame on lo to or from ``port``."""
        while True:
            frame = sock.recv(65535)
            if len(frame) < 34 or frame[12:14] != b"\x08\x00" or frame[23] != 6:  # IPv4, TCP
                continue
            ip = frame[14:]
            ihl = (ip[0] & 0x0F) * 4
            tcp = ip[ihl:]
            src, dst = int.from_bytes(tcp[0:2], "big"), int.from_bytes(tcp[2:4], "big")
            if port in (src, dst):
                payload = tcp[(tcp[12] >> 4) * 4 :]
                if payload:
                    with self.cond:
                        self.sniffed.append(payload)

    def _udp_loop(self, sock: socket.socket) -> None:
        while True:
            data = sock.recv(65535)
            with self.cond:
                self.udp_seen.append(data)

    @staticmethod
    def _loop(lc: lcm.LCM) -> None:
        while True:
            lc.handle_timeout(50)

    def send(self, channel: str, data: bytes, count: int = 1) -> None:
        for _ in range(count):
            for lc in self.buses:
                lc.publish(channel, data)

    def _decoded(
        self, pattern: str, type_name: str, start: int, genuine: bool
    ) -> list[tuple[int, dict[str, Any]]]:
        rx = re.compile(pattern)
        msg_type = MESSAGE_TYPES[type_name]
        out = []
        for i in range(start, len(self.seen)):
            t, channel, data = self.seen[i]
            if not rx.fullmatch(channel):
                continue
            try:
                msg = msg_type.decode(data)
            except Exception:  # noqa: BLE001 - another type on the channel, or garbage
                continue
            # Genuine = signed with the swarm key; freshness is judged at arrival, not now.
            if genuine and (self.key is None or verify(msg, self.key, self.window, now=t) is not None):
                continue
            d = to_dict(msg)
            d["_channel"], d["_index"], d["_t"] = channel, i, t
            out.append((i, d))
        return out

    def handle(self, req: dict[str, Any]) -> dict[str, Any]:
        op = req["op"]
        if op == "publish":
            msg = fill(MESSAGE_TYPES[req["type"]](), req.get("fields", {}))
            if req.get("stamp", True):
                msg.header.utime = int(time.time() * 1e6)
            if req.get("sign"):
                if self.key is None:
                    return {"ok": False, "error": "this peer holds no key"}
                sign(msg, self.key)
            data = msg.encode()
            self.send(req["channel"], data, req.get("count", 1))
            return {"ok": True, "hex": data.hex()}
        if op == "raw":
            self.send(req["channel"], bytes.fromhex(req["hex"]), req.get("count", 1))
            return {"ok": True}
        if op == "sniff_start":
            try:
                sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))
                sock.bind(("lo", 0))
            except OSError as exc:  # a kernel that denies packet sockets even in our own namespace
                return {"ok": False, "error": f"no packet socket: {exc}"}
            threading.Thread(target=self._sniff, args=(sock, int(req["port"])), daemon=True).start()
            return {"ok": True}
        if op == "sniff_take":
            with self.cond:
                data, self.sniffed = b"".join(self.sniffed), []
            return {"ok": True, "hex": data.hex()}
        if op == "udp_open":
            # A UDP socket of the attacker's own; what arrives on it is kept (``udp_recv``).
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            self.udp = sock
            threading.Thread(target=self._udp_loop, args=(sock,), daemon=True).start()
            return {"ok": True, "port": sock.getsockname()[1]}
        if op == "udp_send":
            assert self.udp is not None, "udp_open first"
            for hx in req["hexes"]:
                self.udp.sendto(bytes.fromhex(hx), (req["host"], req["port"]))
                if req.get("gap"):
                    time.sleep(req["gap"])
            return {"ok": True}
        if op == "udp_recv":
            with self.cond:
                got = self.udp_seen[req.get("since", 0) :]
            return {"ok": True, "hexes": [d.hex() for d in got], "index": req.get("since", 0) + len(got)}
        if op == "batch":
            for item in req["items"]:
                self.send(item["channel"], bytes.fromhex(item["hex"]))
                if req.get("gap"):
                    time.sleep(req["gap"])
            return {"ok": True, "sent": len(req["items"])}
        if op in ("replay", "capture"):
            with self.cond:
                hits = [
                    (i, d)
                    for i, d in self._decoded(req["channel"], req["type"], req.get("since", 0), False)
                    if matches(d, req.get("where", {}))
                ]
            if not hits:
                return {"ok": False, "error": "nothing recorded matches"}
            i, d = hits[0] if req.get("pick", "last") == "first" else hits[-1]
            _, channel, data = self.seen[i]
            if op == "replay":
                self.send(channel, data, req.get("count", 1))
            return {"ok": True, "msg": d, "hex": data.hex()}
        if op == "wait":
            deadline = time.time() + req.get("timeout", 10)
            with self.cond:
                while True:
                    found = [
                        d
                        for _, d in self._decoded(
                            req["channel"], req["type"], req.get("since", 0), req.get("genuine", False)
                        )
                        if matches(d, req.get("where", {}))
                    ]
                    if found:
                        return {"ok": True, "msg": found[0]}
                    remaining = deadline - time.time()
                    if remaining <= 0:
                        return {"ok": False}
                    self.cond.wait(min(remaining, 0.2))
        if op == "history":
            with self.cond:
                hits = self._decoded(
                    req["channel"], req["type"], req.get("since", 0), req.get("genuine", False)
                )
            return {"ok": True, "msgs": [d for _, d in hits]}
        if op == "mark":
            with self.cond:
                return {"ok": True, "index": len(self.seen)}
        if op == "http":
            bodies = req.get("bodies")
            responses = []
            client = self.http
            if req.get("source"):  # another of the attacker's addresses
                client = self._clients.get(req["source"]) or self._clients.setdefault(
                    req["source"], self._client(req["source"])
                )
            for body in bodies if bodies is not None else [req.get("json")]:
                try:
                    r = client.request(
                        req["method"],
                        req["url"],
                        json=body if req.get("content") is None else None,
                        content=req.get("content"),
                        headers=req.get("headers"),
                    )
                except httpx.HTTPError as exc:
                    responses.append({"status": 0, "body": f"{type(exc).__name__}: {exc}"})
                    continue
                try:
                    parsed: Any = r.json()
                except ValueError:
                    parsed = r.text[:2000]
                responses.append({"status": r.status_code, "body": parsed})
            return {"ok": True, "responses": responses}
        return {"ok": False, "error": f"unknown op {op}"}


def main() -> None:
    import argparse

    parser = argparse.ArgumentParser()
    parser.add_argument("url", nargs="+")
    parser.add_argument("--key", default=None)
    parser.add_argument("--window", type=float, default=5.0)
    parser.add_argument("--source", default=None, help="local address of HTTP requests")
    parser.add_argument("--ca", default=None, help="CA file that verifies the station (else no verification)")
    args = parser.parse_args()
    serve(Peer(args.url, args.key, args.window, args.source, args.ca).handle)


if __name__ == "__main__":
    main()
