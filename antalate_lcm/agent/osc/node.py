"""The OSC node: reports the agent's state to the station over HTTP(S) and publishes what comes back.

The HTTP exchange is a coroutine on the process's event loop (``Executor.loop``, where the agent's
other nodes run): it awaits the server, so a slow or dead server never stalls them, and a thousand
agents' OSCs in one process need no thread each. A server that is down, slow or answers garbage is
logged (at a limited rate) and retried with exponential backoff; nothing is published from a reply
that did not validate completely.

The OSC never signs for the station. An operator command arrives as the operator signed it and is
published exactly so (header and MAC untouched); with a swarm key the agent's admission pipeline
verifies it first (target, MAC, window, replay: `Node.relay`, `NodeAdmission.vet_relay`) and the OSC drops what fails, so a station that is compromised can delay or drop
commands but not make one up. The station's own payload (peer detection) is published as this
node's message, like anything else the agent says.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import logging
import os
import random
import ssl
from pathlib import Path
from typing import Any

import httpx

from antalate_lcm.agent.osc import wire
from antalate_lcm.base.errors import ConfigError
from antalate_lcm.base.errors import ServerProblem as ServerProblem
from antalate_lcm.base.ratelimit import RateLimitedLog
from antalate_lcm.core.config import Config
from antalate_lcm.core.node import Context, Node, NodeSettings
from antalate_lcm.msgs import hlc_state_t, mc_state_t, payload_t, telemetry_t

# httpx logs every request at INFO: one line per report per agent would drown an agent's log.
logging.getLogger("httpx").setLevel(logging.WARNING)


def _retry_after(response: httpx.Response) -> float:
    try:
        return max(0.0, float(response.headers.get("retry-after", "0")))
    except ValueError:
        return 0.0


@functools.cache
def tls_context(ca_file: str) -> ssl.SSLContext:
    """The certificates an OSC trusts: ``ca_file``'s, or (empty) httpx's default bundle.

    One per CA file and process, shared by its OSCs: a client left to build its own loads the whole
    bundle again, about 850 KiB and 17 ms each (a thousand agents' OSCs: 850 MiB, 17 s of the loop).
    A file that cannot be read raises, and is not cached.
    """
    if ca_file:
        return ssl.create_default_context(cafile=ca_file)
    return httpx.create_ssl_context()


class OscNode(Node):
    kind = "osc"

    def __init__(
        self, config: Config, context: Context, *, transport: httpx.AsyncBaseTransport | None = None
    ) -> None:
        super().__init__(NodeSettings.from_config(config), context)
        #: The agent's whole config, for this node's own logic (the base node reads only its settings).
        self.config = config
        self.osc = config.osc
        self.url = self.osc.server.rstrip("/") + "/api/report"
        try:
            self._verify = tls_context(self.osc.ca_file)
        except (OSError, ssl.SSLError) as exc:
            raise ConfigError(
                config.source,
                "osc.ca_file",
                f"a readable PEM file of CA certificates ({self.osc.ca_file}: {exc})",
            ) from None
        self._token_file = Path(self.osc.token_file).expanduser() if self.osc.token_file else None
        self.token: str | None = self._load_token()
        self.reports_ok = 0
        self.failures = 0
        self.consecutive_failures = 0
        #: Commands from the station not published, by reason (unsigned, forged, stale, ...).
        self.dropped: dict[str, int] = {}
        # Written by the subscriptions and read by the exchange, all on the loop thread: no lock.
        self._latest: dict[str, Any] = {}
        self._feedback: payload_t | None = None
        self._task: asyncio.Task[None] | None = None
        self._transport = transport
        self._problems = RateLimitedLog(self.log, period=30.0)
        self._drops = RateLimitedLog(self.log, period=10.0)

    # ------------------------------------------------------------------ the token
    def _load_token(self) -> str | None:
        if self._token_file is None:
            return None
        try:
            token = self._token_file.read_text(encoding="utf-8").strip()
        except FileNotFoundError:
            return None
        except OSError as exc:
            self.log.warning(
                "cannot read the station token from %s: %s; registering anew", self._token_file, exc
            )
            return None
        return token or None

    def _set_token(self, token: str | None) -> None:
        """Keep the token (in the file too, mode 0600, written atomically), or forget it (None)."""
        self.token = token
        path = self._token_file
        if path is None:
            return
        try:
            if token is None:
                path.unlink(missing_ok=True)
                return
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(path.name + ".tmp")
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(token + "\n")
            os.replace(tmp, path)
        except OSError as exc:
            self._problems.log(
                ("token-file",), logging.WARNING, "cannot keep the station token in %s: %s", path, exc
            )

    # ------------------------------------------------------------------ lifecycle
    def on_start(self) -> None:
        self.subscribe("MC_STATE", lambda m: self._keep("mc", m))
        self.subscribe("HLC_STATE", lambda m: self._keep("hlc", m))
        self.subscribe("TELEMETRY", lambda m: self._keep("telemetry", m))
        self.subscribe("OPERATOR_FEEDBACK", self._on_feedback)
        self._task = self.context.executor.loop.create_task(self._run(), name=f"osc-{self.agent}")
        self.log.info("reporting to %s every %.2f s", self.url, 1.0 / self.osc.rate)
        host = httpx.URL(self.url).host
        if self.url.startswith("http://") and host not in ("127.0.0.1", "localhost", "::1"):
            self.log.warning(
                "the station link %s is not encrypted: the agent's token and reports travel in clear "
                "(use https:// with [osc] ca_file)",
                self.url,
            )

    def on_stop(self) -> None:
        # On the loop thread: the exchange stops at its next await (a request in flight is dropped,
        # its connection closed as the client's ``async with`` unwinds); nothing is sent after this.
        task, self._task = self._task, None
        if task is not None:
            task.cancel()

    @property
    def reporting(self) -> bool:
        """Whether the exchange with the station is running (it outlives every server problem)."""
        return self._task is not None and not self._task.done()

    # ------------------------------------------------------------------ inputs (loop thread)
    def _keep(self, key: str, msg: Any) -> None:
        self._latest[key] = msg

    def _on_feedback(self, msg: payload_t) -> None:
        self._feedback = msg

    # ------------------------------------------------------------------ the HTTP exchange (a coroutine)
    async def _run(self) -> None:
        period = 1.0 / self.osc.rate
        async with httpx.AsyncClient(
            timeout=self.osc.timeout, transport=self._transport, verify=self._verify
        ) as client:
            delay = 0.0
            while True:
                await asyncio.sleep(delay)
                try:
                    await self._exchange(client)
                except ServerProblem as exc:
                    self.failures += 1
                    self.consecutive_failures += 1
                    backoff = min(self.osc.max_backoff, period * 2 ** min(self.consecutive_failures, 16))
                    delay = max(backoff * random.uniform(0.8, 1.2), exc.retry_after)
                    self._problems.log(
                        ("problem", type(exc.__cause__).__name__ if exc.__cause__ else str(exc)[:40]),
                        logging.WARNING,
                        "station %s: %s; retrying in %.1f s",
                        self.url,
                        exc,
                        delay,
                    )
                    continue
                except Exception:  # a bug here must not end the reports for good: said, backed off
                    self.failures += 1
                    self.consecutive_failures += 1
                    delay = self.osc.max_backoff
                    self.log.exception(
                        "the exchange with station %s failed; retrying in %.1f s", self.url, delay
                    )
                    continue
                if self.consecutive_failures:
                    self.log.info(
                        "station %s answers again after %d failure(s)", self.url, self.consecutive_failures
                    )
                self.consecutive_failures = 0
                self.reports_ok += 1
                delay = period

    async def _exchange(self, client: httpx.AsyncClient) -> None:
        mc: mc_state_t | None = self._latest.get("mc")
        hlc: hlc_state_t | None = self._latest.get("hlc")
        telemetry: telemetry_t | None = self._latest.get("telemetry")
        feedback, self._feedback = self._feedback, None
        body = wire.report_body(
            self.token,
            mc,
            hlc,
            telemetry,
            feedback,
            agent=self.agent,
            swarm_key=self.config.security.swarm_key,
        )
        try:
            async with client.stream("POST", self.url, json=body) as response:
                raw = await self._read_capped(response)
                status = response.status_code
                retry_after = _retry_after(response)
        except httpx.TimeoutException as exc:
            self._requeue(feedback)
            raise ServerProblem(f"no answer within {self.osc.timeout:g} s") from exc
        except httpx.HTTPError as exc:
            self._requeue(feedback)
            raise ServerProblem(f"cannot reach it ({exc.__class__.__name__}: {exc})") from exc
        if status != 200:
            self._requeue(feedback)
            text = raw[:300].decode("utf-8", "replace")
            with contextlib.suppress(ValueError, AttributeError):
                text = str(json.loads(raw)["detail"])[:300]
            if status in (401, 409) and self.token is not None:
                # The station does not know this token (reset, or it was replaced by a proven
                # re-registration): forget it and register at the next report.
                self._set_token(None)
                raise ServerProblem(f"HTTP {status}: {text}; registering again", retry_after=0.0)
            raise ServerProblem(f"HTTP {status}: {text}", retry_after=retry_after)
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
            self.log.info("registered with the station as %r", self.agent)
            self._set_token(reply.token)
        for topic, msg, original in messages:
            if msg is not None:
                seq = original.seq if original is not None else None
                signed = original is not None and original.mac is not None
                self._publish(topic, msg, seq, signed)

    async def _read_capped(self, response: httpx.Response) -> bytes:
        limit = self.osc.max_reply_bytes
        chunks: list[bytes] = []
        size = 0
        async for chunk in response.aiter_bytes():
            size += len(chunk)
            if size > limit:
                raise ServerProblem(f"reply larger than {limit} bytes, ignored")
            chunks.append(chunk)
        return b"".join(chunks)

    def _requeue(self, feedback: payload_t | None) -> None:
        if feedback is None:
            return
        if self._feedback is None:
            self._feedback = feedback

    def _drop(self, reason: str, topic: str, msg: Any, text: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1
        self._drops.log(
            (reason, topic),
            logging.WARNING,
            "dropped %s from the station (sender %r, seq %d): %s (%d %s so far)",
            topic,
            msg.header.agent,
            msg.header.seq,
            text,
            self.dropped[reason],
            reason,
        )

    def _publish(self, topic: str, msg: Any, seq: int | None, signed: bool = False) -> None:
        if not self.started:
            return
        if topic == "OPERATOR_PAYLOAD":
            self.publish(topic, msg)  # the station's own payload: this node's message
            self.log.debug("from the station: %s", topic)
            return
        # The admission vets it (`Node.relay`, `NodeAdmission.vet_relay`): signed, it goes out as the operator
        # signed it (no new header, no signature of ours); unsigned, only from a keyless agent.
        refusal = self.relay(topic, msg, signed=signed, seq=seq)
        if refusal is not None:
            if refusal.logged:  # counted and logged (rate-limited) by the authenticator
                self.dropped[refusal.reason] = self.dropped.get(refusal.reason, 0) + 1
            else:
                self._drop(refusal.reason, topic, msg, refusal.text)
            return
        if not signed:
            self.log.info("from the station: %s (seq %s, unsigned)", topic, seq)
            return
        self.log.info("from the station: %s signed by %r (seq %d)", topic, msg.header.agent, msg.header.seq)
