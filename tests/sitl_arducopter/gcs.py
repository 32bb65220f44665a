"""A second MAVLink client of a SITL ArduCopter, driven by JSON lines inside the test's network namespace.

The vehicle's own record for the SITL tests (what it did, whatever antalate believes) and the hands of
everyone else on the link: the pilot who changes the mode, the test that injects a failure through
ArduPilot's SIM_* parameters. It talks to SITL's SERIAL1 (tcp 5762+10N) as system 250, so neither the
vehicle's GCS failsafe (SYSID_MYGCS) nor the adapter's acknowledgements (system 245) are confused by it.

Requests (one JSON object a line), one JSON reply line each:
- ``{"op": "connect"}``: connect to SERIAL1 (SITL opens it once SERIAL0, the relay, has its client);
- ``{"op": "state"}``: the latest mode, armed, landed state, relative altitude, metres north/east of home,
  battery voltage and health (SYS_STATUS) and the highest altitude since the last ``mark``;
- ``{"op": "mark"}``: starts a new record (``modes``, ``texts``, ``max_alt`` count from here);
- ``{"op": "record"}``: the mode changes and STATUSTEXTs (with their severity) since the last mark;
- ``{"op": "set_param", "name": N, "value": V}``: PARAM_SET, confirmed by PARAM_VALUE;
- ``{"op": "set_mode", "mode": M}``: MAV_CMD_DO_SET_MODE as a pilot's ground station would;
- ``{"op": "command", "command": C, "params": [...]}``: any COMMAND_LONG, answered by its COMMAND_ACK;
- ``{"op": "relay", "mode": "pass" | "cut" | "stall"}``: the adapter's link (`relay.Relay`).

``python -m tests.sitl_arducopter.gcs SERIAL1_URL RELAY_PORT SERIAL0_PORT`` starts the relay first (the
agent connects through it), then connects to SERIAL1, which SITL opens once SERIAL0 has its client.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.autopilot.mavlink.dialect import COPTER_MODES, mode_name
from antalate_lcm.geo import local_ne
from tests.sitl_arducopter.relay import Relay

SYSTEM = 250  # neither SYSID_MYGCS (245 in these tests) nor the adapter
ACK_TIMEOUT = 3.0


class Gcs:
    def __init__(self, url: str) -> None:
        deadline = time.monotonic() + 60
        while True:
            try:
                self.conn = mavutil.mavlink_connection(url, source_system=SYSTEM, source_component=190)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        self.lock = threading.Condition()
        self.state: dict[str, Any] = {"mode": "", "armed": False, "alt": 0.0, "north": 0.0, "east": 0.0}
        self.home: tuple[float, float] | None = None
        self.modes: list[tuple[float, str]] = []
        self.texts: list[tuple[float, int, str]] = []
        self.max_alt = 0.0
        self.params: dict[str, tuple[float, float]] = {}  # name -> (value, time)
        self.acks: dict[int, tuple[int, float]] = {}
        self.target = (1, 1)
        threading.Thread(target=self._rx, daemon=True).start()
        threading.Thread(target=self._tx, daemon=True).start()

    def _tx(self) -> None:
        streams_at = 0.0
        while True:
            self.conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            now = time.monotonic()
            if now - streams_at > 5:  # the vehicle keeps per-link rates; a reboot resets them
                streams_at = now
                self.conn.mav.request_data_stream_send(*self.target, mav.MAV_DATA_STREAM_ALL, 10, 1)
            time.sleep(1)

    def _rx(self) -> None:
        while True:
            msg = self.conn.recv_match(blocking=True, timeout=0.5)
            if msg is None or msg.get_srcComponent() != 1:
                continue
            t = msg.get_type()
            now = time.monotonic()
            with self.lock:
                if t == "HEARTBEAT":
                    self.target = (msg.get_srcSystem(), 1)
                    mode = mode_name(msg.custom_mode)
                    if mode != self.state["mode"]:
                        self.modes.append((now, mode))
                    self.state.update(
                        mode=mode,
                        armed=bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED),
                        system_status=msg.system_status,
                    )
                elif t == "GLOBAL_POSITION_INT":
                    lat, lon = msg.lat / 1e7, msg.lon / 1e7
                    alt = msg.relative_alt / 1000.0
                    self.max_alt = max(self.max_alt, alt)
                    north = east = 0.0
                    if self.home is not None:
                        north, east = local_ne(*self.home, lat, lon)
                    self.state.update(alt=alt, lat=lat, lon=lon, north=north, east=east)
                elif t == "HOME_POSITION":
                    self.home = (msg.latitude / 1e7, msg.longitude / 1e7)
                elif t == "EXTENDED_SYS_STATE":
                    self.state["landed_state"] = msg.landed_state
                elif t == "SYS_STATUS":
                    self.state["voltage"] = msg.voltage_battery / 1000.0
                    bit = mav.MAV_SYS_STATUS_SENSOR_BATTERY
                    self.state["battery_healthy"] = bool(msg.onboard_control_sensors_health & bit)
                elif t == "STATUSTEXT":
                    self.texts.append((now, msg.severity, msg.text))
                elif t == "PARAM_VALUE":
                    self.params[msg.param_id] = (msg.param_value, now)
                elif t == "COMMAND_ACK" and getattr(msg, "target_system", SYSTEM) in (0, SYSTEM):
                    self.acks[msg.command] = (msg.result, now)
                self.lock.notify_all()
            if t == "HEARTBEAT" and self.home is None:
                self.conn.mav.command_long_send(
                    *self.target,
                    mav.MAV_CMD_REQUEST_MESSAGE,
                    0,
                    mav.MAVLINK_MSG_ID_HOME_POSITION,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                )

    def _wait(self, predicate: Any, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        with self.lock:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.lock.wait(left)
        return True

    def set_param(self, name: str, value: float) -> dict[str, Any]:
        for _ in range(3):
            sent = time.monotonic()
            self.conn.mav.param_set_send(*self.target, name.encode(), value, mav.MAV_PARAM_TYPE_REAL32)

            def confirmed(sent: float = sent) -> bool:
                got = self.params.get(name)
                return got is not None and got[1] >= sent and abs(got[0] - value) <= 1e-3 * max(1, abs(value))

            if self._wait(confirmed, ACK_TIMEOUT):
                return {"ok": True}
        return {"ok": False, "error": f"{name} = {value} not confirmed: {self.params.get(name)}"}

    def set_mode(self, mode: str) -> dict[str, Any]:
        sent = time.monotonic()
        cmd = mav.MAV_CMD_DO_SET_MODE
        self.conn.mav.command_long_send(
            *self.target, cmd, 0, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, COPTER_MODES[mode], 0, 0, 0, 0, 0
        )
        if not self._wait(lambda: cmd in self.acks and self.acks[cmd][1] >= sent, ACK_TIMEOUT):
            return {"ok": False, "error": "no COMMAND_ACK"}
        return {"ok": self.acks[cmd][0] == mav.MAV_RESULT_ACCEPTED, "result": self.acks[cmd][0]}

    def command(self, command: int, params: list[float]) -> dict[str, Any]:
        sent = time.monotonic()
        self.conn.mav.command_long_send(*self.target, command, 0, *(list(params) + [0.0] * 7)[:7])
        if not self._wait(lambda: command in self.acks and self.acks[command][1] >= sent, ACK_TIMEOUT):
            return {"ok": False, "error": f"no COMMAND_ACK for {command}"}
        return {"ok": self.acks[command][0] == mav.MAV_RESULT_ACCEPTED, "result": self.acks[command][0]}

    def handle(self, req: dict[str, Any]) -> dict[str, Any]:
        op = req["op"]
        if op == "set_param":
            return self.set_param(req["name"], float(req["value"]))
        if op == "command":
            return self.command(int(req["command"]), [float(p) for p in req.get("params", [])])
        if op == "set_mode":
            return self.set_mode(req["mode"])
        with self.lock:
            if op == "state":
                return {"ok": True, **self.state, "max_alt": self.max_alt, "home": self.home is not None}
            if op == "mark":
                self.modes, self.texts, self.max_alt = [], [], self.state["alt"]
                return {"ok": True}
            if op == "record":
                return {"ok": True, "modes": self.modes, "texts": self.texts, "max_alt": self.max_alt}
        return {"ok": False, "error": f"unknown op {op!r}"}


def main() -> None:
    out, sys.stdout = sys.stdout, sys.stderr  # pymavlink prints its retries: keep them off the replies
    relay = Relay(int(sys.argv[2]), int(sys.argv[3]))
    print(json.dumps({"ready": True}), file=out, flush=True)
    gcs: Gcs | None = None
    reply: dict[str, Any]
    for line in sys.stdin:
        try:
            req = json.loads(line)
            if req["op"] == "relay":
                relay.set_mode(req["mode"])
                reply = {"ok": True}
            elif req["op"] == "connect":
                gcs = gcs or Gcs(sys.argv[1])
                reply = {"ok": True}
            elif gcs is None:
                reply = {"ok": False, "error": "not connected to SERIAL1 yet (op connect)"}
            else:
                reply = gcs.handle(req)
        except Exception as exc:  # noqa: BLE001 - the test reads the error
            reply = {"ok": False, "error": repr(exc)}
        print(json.dumps(reply), file=out, flush=True)


if __name__ == "__main__":
    main()
