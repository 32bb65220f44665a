"""The OSC node: reports the agent's state to the station over HTTP and publishes what comes back.

The HTTP exchange runs on a thread of its own, so a slow or dead server never stalls the executor
the agent's other nodes share. A server that is down, slow or answers garbage is logged (at a limited
rate) and retried with exponential backoff; nothing is published from a reply that did not validate
completely.
"""

from __future__ import annotations

import logging
import random
import threading
from typing import Any

import httpx

from antalate_lcm._ratelimit import RateLimitedLog
from antalate_lcm.config import Config
from antalate_lcm.msgs import direction_cmd_t, hlc_state_t, mc_state_t, operator_cmd_t, payload_t, telemetry_t
from antalate_lcm.node import Context, Node
from antalate_lcm.osc import wire
from antalate_lcm.security import sign


class ServerProblem(Exception):
    """One failed exchange with the station (down, timeout, wrong status, oversized or invalid reply)."""


class OscNode(Node):
    kind = "osc"

    def __init__(
        self, config: Config, context: Context, *, transport: httpx.BaseTransport | None = None
    ) -> None:
        super().__init__(config, context)
        self.osc = config.osc
        self.url = self.osc.server.rstrip("/") + "/api/report"
        self.token: str | None = None
        self.reports_ok = 0
        self.failures = 0
        self.consecutive_failures = 0
        self._latest: dict[str, Any] = {}
        self._feedback: payload_t | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._transport = transport
        self._problems = RateLimitedLog(self.log, period=30.0)

    # ------------------------------------------------------------------ lifecycle
    def on_start(self) -> None:
        self.subscribe("MC_STATE", lambda m: self._keep("mc", m))
        self.subscribe("HLC_STATE", lambda m: self._keep("hlc", m))
        self.subscribe("TELEMETRY", lambda m: self._keep("telemetry", m))
        self.subscribe("OPERATOR_FEEDBACK", self._on_feedback)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"osc-{self.agent}", daemon=True)
        self._thread.start()
        self.log.info("reporting to %s every %.2f s", self.url, 1.0 / self.osc.rate)

    def on_stop(self) -> None:
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=self.osc.timeout + 1.0)

    # ------------------------------------------------------------------ inputs (executor thread)
    def _keep(self, key: str, msg: Any) -> None:
        with self._lock:
            self._latest[key] = msg

    def _on_feedback(self, msg: payload_t) -> None:
        with self._lock:
            self._feedback = msg

    # ------------------------------------------------------------------ the HTTP loop (own thread)
    def _run(self) -> None:
        period = 1.0 / self.osc.rate
        with httpx.Client(timeout=self.osc.timeout, transport=self._transport) as client:
            delay = 0.0
            while not self._stop.wait(delay):
                try:
                    self._exchange(client)
                except ServerProblem as exc:
                    self.failures += 1
                    self.consecutive_failures += 1
                    backoff = min(self.osc.max_backoff, period * 2 ** min(self.consecutive_failures, 16))
                    delay = backoff * random.uniform(0.8, 1.2)
                    self._problems.log(
                        ("problem", type(exc.__cause__).__name__ if exc.__cause__ else str(exc)[:40]),
                        logging.WARNING,
                        "station %s: %s; retrying in %.1f s",
                        self.url,
                        exc,
                        delay,
                    )
                    continue
                if self.consecutive_failures:
                    self.log.info(
                        "station %s answers again after %d failure(s)", self.url, self.consecutive_failures
                    )
                self.consecutive_failures = 0
                self.reports_ok += 1
                delay = period

    def _exchange(self, client: httpx.Client) -> None:
        with self._lock:
            mc: mc_state_t | None = self._latest.get("mc")
            hlc: hlc_state_t | None = self._latest.get("hlc")
            telemetry: telemetry_t | None = self._latest.get("telemetry")
            feedback, self._feedback = self._feedback, None
        body = wire.report_body(self.token, mc, hlc, telemetry, feedback)
        try:
            with client.stream("POST", self.url, json=body) as response:
                raw = self._read_capped(response)
                status = response.status_code
        except httpx.TimeoutException as exc:
            self._requeue(feedback)
            raise ServerProblem(f"no answer within {self.osc.timeout:g} s") from exc
        except httpx.HTTPError as exc:
            self._requeue(feedback)
            raise ServerProblem(f"cannot reach it ({exc.__class__.__name__}: {exc})") from exc
        if status != 200:
            self._requeue(feedback)
            raise ServerProblem(f"HTTP {status}: {raw[:200].decode('utf-8', 'replace')}")
        try:
            reply = wire.parse_reply(raw)
            messages = (
                ("OPERATOR_CMD", wire.operator_cmd(reply, self.agent), reply.operator_cmd),
                ("DIRECTION_CMD", wire.direction_cmd(reply, self.agent), reply.direction_cmd),
                ("OPERATOR_PAYLOAD", wire.payload(reply), None),
            )
        except wire.ReplyError as exc:
            raise ServerProblem(f"invalid reply, ignored: {exc}") from None
        if reply.token != self.token:
            if self.token is not None:
                self.log.info("the station gave a new token (it did not know %s)", self.token)
            self.token = reply.token
        for topic, msg, original in messages:
            if msg is not None:
                seq = original.seq if original is not None else None
                self.context.executor.call_soon(self._publish, topic, msg, seq)

    def _read_capped(self, response: httpx.Response) -> bytes:
        limit = self.osc.max_reply_bytes
        chunks: list[bytes] = []
        size = 0
        for chunk in response.iter_bytes():
            size += len(chunk)
            if size > limit:
                raise ServerProblem(f"reply larger than {limit} bytes, ignored")
            chunks.append(chunk)
        return b"".join(chunks)

    def _requeue(self, feedback: payload_t | None) -> None:
        if feedback is None:
            return
        with self._lock:
            if self._feedback is None:
                self._feedback = feedback

    def _publish(self, topic: str, msg: Any, seq: int | None) -> None:
        if not self.started:
            return
        key = self.config.security.swarm_key
        signer = (lambda m: sign(m, key)) if key and isinstance(msg, (operator_cmd_t, direction_cmd_t)) else None
        self.publish(topic, msg, seq=seq, before_encode=signer)
        level = logging.INFO if seq is not None else logging.DEBUG
        self.log.log(level, "from the station: %s%s", topic, f" (seq {seq})" if seq is not None else "")
