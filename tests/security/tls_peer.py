"""Zenoh clients with and without credentials, and an in-process router, inside the test's namespace
(issue 29, finding 7: tests/security/test_router_tls.py).

Requests, one JSON object a line, one JSON reply line each (``{"ok": bool, ...}``):

``open``    {id, endpoint, ca?, cert?, key?, auth?, timeout}: a Zenoh client session with exactly these
            credentials (file paths; ``auth`` a user:password file, read as the bus reads it);
            ``opened``: whether the router let it in, ``error`` why not
``sub``     {id, key}: subscribe (keys received are kept); ``got`` {id}: the keys received so far
``put``     {id, key}: put a few bytes; ``close`` {id}
``router``  {listen, cert, key, ca?, prefixes}: a router from :func:`antalate_lcm.runtime.router.router_config`
            (the code ``antalate router`` runs) with a subscriber on ``**`` of its own: what reaches the
            router past its access control; ``router_got``: those keys
"""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import zenoh

from antalate_lcm.runtime.router import router_config
from antalate_lcm.transports.zenoh import read_credentials, tls_settings
from tests.harness.jsonl import serve


class Peer:
    def __init__(self) -> None:
        self.sessions: dict[str, Any] = {}
        self.subs: list[Any] = []
        self.got: dict[str, list[str]] = {}
        self.lock = threading.Lock()
        self.router: Any = None

    def _record(self, who: str, sample: Any) -> None:
        with self.lock:
            self.got.setdefault(who, []).append(str(sample.key_expr))

    def handle(self, req: dict[str, Any]) -> dict[str, Any]:
        op = req["op"]
        if op == "open":
            config = zenoh.Config()
            config.insert_json5("mode", '"client"')
            config.insert_json5("connect/endpoints", json.dumps([req["endpoint"]]))
            config.insert_json5("scouting/multicast/enabled", "false")
            config.insert_json5(
                "connect/timeout_ms", json.dumps({"client": int(req.get("timeout", 3) * 1000)})
            )
            tls = tls_settings(ca=req.get("ca"), cert=req.get("cert"), key=req.get("key"))
            if tls:
                config.insert_json5("transport/link/tls", json.dumps(tls))
            if req.get("auth"):
                user, password = read_credentials(req["auth"])
                config.insert_json5("transport/auth/usrpwd", json.dumps({"user": user, "password": password}))
            t0 = time.monotonic()
            try:
                self.sessions[req["id"]] = zenoh.open(config)
            except zenoh.ZError as exc:
                return {"ok": True, "opened": False, "error": str(exc)[:200], "took": time.monotonic() - t0}
            return {"ok": True, "opened": True}
        if op == "sub":
            who = req["id"]
            self.subs.append(
                self.sessions[who].declare_subscriber(req["key"], lambda s, who=who: self._record(who, s))
            )
            return {"ok": True}
        if op == "got":
            with self.lock:
                return {"ok": True, "keys": sorted(set(self.got.get(req["id"], [])))}
        if op == "put":
            self.sessions[req["id"]].put(req["key"], b"x" * 8)
            return {"ok": True}
        if op == "close":
            self.sessions.pop(req["id"]).close()
            return {"ok": True}
        if op == "router":
            self.router = zenoh.open(
                router_config(
                    [req["listen"]],
                    3000,
                    tls_cert=req["cert"],
                    tls_key=req["key"],
                    ca=req.get("ca"),
                    prefixes=req["prefixes"],
                )
            )
            self.subs.append(self.router.declare_subscriber("**", lambda s: self._record("@router", s)))
            return {"ok": True}
        if op == "router_got":
            with self.lock:
                return {"ok": True, "keys": sorted(set(self.got.get("@router", [])))}
        return {"ok": False, "error": f"unknown op {op!r}"}


def main() -> None:
    serve(Peer().handle)


if __name__ == "__main__":
    main()
