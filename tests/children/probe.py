"""A scriptable LCM peer that tests run inside a network namespace, driven by JSON lines on stdin
(``python -m tests.children.probe URL``; its client is the `probe` fixture of tests/conftest.py).

Requests (one JSON object a line) and one JSON reply line each:
- ``{"op": "publish", "channel": C, "type": "operator_cmd_t", "fields": {...}}``
- ``{"op": "wait", "channel": REGEX, "type": T, "where": {...}, "timeout": S}``: the first message
  received (since the probe started) whose fields match ``where``; ``{"ok": false}`` on timeout.
- ``{"op": "history", "channel": REGEX, "type": T}``: every message seen on matching channels.
- ``{"op": "raw", "channel": C, "hex": H}``: publish raw bytes (garbage datagrams).
"""

from __future__ import annotations

import re
import sys
import threading
import time
from typing import Any

import lcm

from antalate_lcm.wire.topics import MESSAGE_TYPES
from tests.harness.jsonl import serve


def to_dict(msg: Any) -> Any:
    if hasattr(msg, "__slots__"):
        return {k: to_dict(getattr(msg, k)) for k in msg.__slots__}
    if isinstance(msg, list | tuple):
        return [to_dict(x) for x in msg]
    if isinstance(msg, bytes):
        return msg.hex()
    return msg


def fill(msg: Any, fields: dict[str, Any]) -> Any:
    for key, value in fields.items():
        current = getattr(msg, key)
        if isinstance(value, dict) and hasattr(current, "__slots__"):
            fill(current, value)
        elif key == "mac" and isinstance(value, str):
            setattr(msg, key, bytes.fromhex(value))
        else:
            setattr(msg, key, value)
    return msg


def matches(d: dict[str, Any], where: dict[str, Any]) -> bool:
    for key, value in where.items():
        if isinstance(value, dict):
            if not isinstance(d.get(key), dict) or not matches(d[key], value):
                return False
        elif d.get(key) != value:
            return False
    return True


def main() -> None:
    url = sys.argv[1] if len(sys.argv) > 1 else "udpm://239.255.76.67:7667?ttl=0"
    lc = lcm.LCM(url)
    seen: list[tuple[float, str, bytes]] = []
    cond = threading.Condition()

    def on_msg(channel: str, data: bytes) -> None:
        with cond:
            seen.append((time.time(), channel, data))
            cond.notify_all()

    lc.subscribe(".*", on_msg).set_queue_capacity(100000)
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            lc.handle_timeout(50)

    threading.Thread(target=loop, daemon=True).start()

    def decoded(pattern: re.Pattern[str], type_name: str, start: int = 0) -> list[tuple[int, dict[str, Any]]]:
        out = []
        msg_type = MESSAGE_TYPES[type_name]
        for i in range(start, len(seen)):
            _, channel, data = seen[i]
            if pattern.fullmatch(channel):
                try:
                    d = to_dict(msg_type.decode(data))
                except Exception:  # noqa: BLE001 - other types on the channel
                    continue
                d["_channel"] = channel
                out.append((i, d))
        return out

    def handle(req: dict[str, Any]) -> dict[str, Any]:
        op = req["op"]
        if op == "publish":
            msg = fill(MESSAGE_TYPES[req["type"]](), req.get("fields", {}))
            lc.publish(req["channel"], msg.encode())
            return {"ok": True}
        if op == "raw":
            lc.publish(req["channel"], bytes.fromhex(req["hex"]))
            return {"ok": True}
        if op == "wait":
            pattern = re.compile(req["channel"])
            deadline = time.time() + req.get("timeout", 10)
            start = req.get("since", 0)
            with cond:
                while True:
                    hits = [
                        d for _, d in decoded(pattern, req["type"], start) if matches(d, req.get("where", {}))
                    ]
                    if hits:
                        return {"ok": True, "msg": hits[0]}
                    remaining = deadline - time.time()
                    if remaining <= 0:
                        return {"ok": False}
                    cond.wait(min(remaining, 0.2))
        if op == "history":
            with cond:
                recorded = decoded(re.compile(req["channel"]), req["type"], req.get("since", 0))
                return {"ok": True, "msgs": [d for _, d in recorded]}
        if op == "mark":
            with cond:
                return {"ok": True, "index": len(seen)}
        return {"ok": False, "error": f"unknown op {op}"}

    serve(handle)
    stop.set()


if __name__ == "__main__":
    main()
