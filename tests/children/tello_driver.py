"""The Tello adapter in a process of its own, driven over JSON lines on stdin/stdout
(tests/vehicles/test_tello_adapter.py's ``Driver`` is the other end).

Each request names an adapter (``name``, default "main") and an ``op``: ``new`` (params), ``call``
(method, args), ``start``/``result`` (a call on a thread of its own, for another caller while one
blocks), ``state`` or ``extra``. Each reply is ``{"ok": ..., "result" | "type" + "error", "elapsed"}``.

    python -m tests.children.tello_driver
"""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from dataclasses import asdict
from typing import Any

from antalate_lcm.vehicles.base import Frame
from antalate_lcm.vehicles.tello import TelloAdapter

adapters: dict[str, TelloAdapter] = {}
background: dict[str, dict[str, Any]] = {}


def run_call(name: str, method: str, args: list[Any]) -> dict[str, Any]:
    try:
        return {"ok": True, "result": getattr(adapters[name], method)(*args)}
    except Exception as exc:
        return {"ok": False, "type": type(exc).__name__, "error": str(exc)}


def start_call(name: str, req: dict[str, Any]) -> None:
    """Run the call on a thread of its own; ``result`` joins it."""
    box: dict[str, Any] = {"t0": time.monotonic()}

    def target() -> None:
        box.update(run_call(name, req["method"], list(req.get("args", []))))
        box["elapsed"] = time.monotonic() - box["t0"]

    box["thread"] = threading.Thread(target=target, daemon=True)
    background[req["tag"]] = box
    box["thread"].start()


def handle(req: dict[str, Any]) -> Any:
    name = req.get("name", "main")
    op = req["op"]
    if op == "new":
        old = adapters.pop(name, None)
        if old is not None:
            old.close()
        adapters[name] = TelloAdapter(req["params"])
        return None
    if op == "call":
        args = list(req.get("args", []))
        if req["method"] == "set_velocity":
            args[4] = Frame[args[4]]
        return getattr(adapters[name], req["method"])(*args)
    if op == "start":
        start_call(name, req)
        return None
    if op == "result":
        box = background.pop(req["tag"])
        box["thread"].join(req.get("timeout", 30))
        return {k: v for k, v in box.items() if k not in ("thread", "t0")}
    if op == "state":
        s = adapters[name].state()
        assert s.flight_mode is not None
        return {**asdict(s), "flight_mode": s.flight_mode.value}
    if op == "extra":
        ap = adapters[name]
        return {
            "position_ne": ap.position_ne,
            "takeoff_point": ap.takeoff_point,
            "dead_reckoning_problem": ap.dead_reckoning_problem,
        }
    raise ValueError(f"unknown op {op}")


def main() -> None:
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="%(asctime)s %(name)s %(message)s")
    for line in sys.stdin:
        req = json.loads(line)
        t0 = time.monotonic()
        try:
            out: dict[str, Any] = {"ok": True, "result": handle(req)}
        except Exception as exc:
            out = {"ok": False, "type": type(exc).__name__, "error": str(exc)}
        out["elapsed"] = time.monotonic() - t0
        sys.stdout.write(json.dumps(out) + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
