"""A second MAVLink client of a SITL vehicle, driven by JSON lines inside the test's network namespace.

The vehicle's own record for the SITL tests (what it did, whatever antalate believes) and the hands of
everyone else on the link: the pilot who changes the mode, the test that injects a failure through the
simulator's SIM_* parameters. It talks as system 250, so neither the vehicle's GCS failsafe
(SYSID_MYGCS) nor the adapter's acknowledgements (system 245) are confused by it:

* ArduCopter (``--stack arducopter``): SITL's SERIAL1 (tcp 5762+10N), with ArduCopter's mode numbers;
* PX4 (``--stack px4``): PX4's GCS link (it sends to udp 14550 from 18570+N, every instance to the same
  port, told apart by system id), with PX4's (main, sub) modes and byte-wise integer parameters. It
  sends no HEARTBEAT there: PX4's data-link-loss failsafe (NAV_DLL_ACT) counts any ground station's
  HEARTBEAT, and the tests want it to see antalate's alone.

Requests (one JSON object a line), one JSON reply line each:
- ``{"op": "connect"}``: connect to SERIAL1 (SITL opens it once SERIAL0, the relay, has its client);
- ``{"op": "state"}``: the latest mode, armed, landed state, relative altitude, metres north/east of home,
  battery voltage and health (SYS_STATUS ``battery_healthy``) and the highest altitude since the last
  ``mark``; with PX4 also its own local position (``x``/``y``/``z``/``vx``/``vy``, LOCAL_POSITION_NED),
  the velocity it is told to fly (``target_vx``, ``target_vy``, POSITION_TARGET_LOCAL_NED) and
  ``battery_remaining`` (%); ``"system": S`` picks one of several vehicles on the link (default: the
  last heard);
- ``{"op": "mark"}``: starts a new record (``modes``, ``texts``, ``max_alt`` count from here);
- ``{"op": "record"}``: the mode changes and STATUSTEXTs (with their severity) since the last mark;
- ``{"op": "set_param", "name": N, "value": V}``: PARAM_SET, confirmed by PARAM_VALUE (``"int": true``
  for a PX4 integer parameter);
- ``{"op": "get_param", "name": N}``: PARAM_REQUEST_READ, the vehicle's PARAM_VALUE (``value``);
- ``{"op": "set_mode", "mode": M}``: MAV_CMD_DO_SET_MODE as a pilot's ground station would;
- ``{"op": "command", "command": C, "params": [...]}``: any COMMAND_LONG, answered by its COMMAND_ACK;
- ``{"op": "relay", "mode": "pass" | "cut" | "stall"}``: the adapter's link (`relay.Relay`, `relay.UdpRelay`).

``python -m tests.sitl_arducopter.gcs URL [--stack px4] [--tcp-relay LISTEN:UPSTREAM | --udp-relay
LISTEN:ADAPTER]`` starts the relay first (the agent connects through it), then, at ``connect``, the
link ``URL`` (SITL ArduCopter opens SERIAL1 once SERIAL0 has its client).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from antalate_lcm.base.geo import local_ne
from antalate_lcm.vehicles.mavlink.dialect import COPTER_MODES, mode_name
from antalate_lcm.vehicles.px4 import modes as px4_modes
from antalate_lcm.vehicles.px4.vehicle import decode_param, encode_param
from tests.sitl_arducopter.relay import Relay, UdpRelay

SYSTEM = 250  # neither SYSID_MYGCS (245 in these tests) nor the adapter
ACK_TIMEOUT = 3.0
#: PX4's GCS link streams (message id -> Hz, 0 = off) this helper asks for (`Gcs._slow_down`).
SLOW_STREAMS = {
    mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10,
    mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10,
    mav.MAVLINK_MSG_ID_ATTITUDE: 0,
    mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 0,
    mav.MAVLINK_MSG_ID_ATTITUDE_TARGET: 0,
    mav.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 2,  # what PX4 is told to fly
    mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: 0,
    mav.MAVLINK_MSG_ID_RC_CHANNELS: 0,
    mav.MAVLINK_MSG_ID_OPTICAL_FLOW_RAD: 0,
    mav.MAVLINK_MSG_ID_HIGHRES_IMU: 0,
    mav.MAVLINK_MSG_ID_ACTUATOR_CONTROL_TARGET: 0,
}


class Gcs:
    def __init__(self, url: str, stack: str = "arducopter") -> None:
        self.px4 = stack == "px4"
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
        self.states: dict[int, dict[str, Any]] = {}
        self.homes: dict[int, tuple[float, float]] = {}
        self.modes: list[tuple[float, str]] = []
        self.texts: list[tuple[float, int, str]] = []
        self.max_alt = 0.0
        self.params: dict[str, tuple[float, float]] = {}  # name -> (value, time)
        self.acks: dict[int, tuple[int, float]] = {}
        self.slowed: set[int] = set()
        self.target = (1, 1)
        threading.Thread(target=self._rx, daemon=True).start()
        threading.Thread(target=self._tx, daemon=True).start()

    @property
    def state(self) -> dict[str, Any]:
        """The vehicle last heard from (the one the tests of one vehicle speak of)."""
        return self.states.setdefault(self.target[0], self._blank())

    @property
    def home(self) -> tuple[float, float] | None:
        return self.homes.get(self.target[0])

    @staticmethod
    def _blank() -> dict[str, Any]:
        return {"mode": "", "armed": False, "alt": 0.0, "north": 0.0, "east": 0.0}

    def _tx(self) -> None:
        streams_at = 0.0
        while self.px4:  # PX4 streams on its GCS link unasked; our HEARTBEAT would mask NAV_DLL_ACT
            time.sleep(3600)
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
            system = msg.get_srcSystem()
            with self.lock:
                state = self.states.setdefault(system, self._blank())
                home = self.homes.get(system)
                if t == "HEARTBEAT":
                    if msg.type in (mav.MAV_TYPE_GCS, mav.MAV_TYPE_ONBOARD_CONTROLLER):
                        continue
                    self.target = (system, 1)
                    mode = px4_modes.mode_name(msg.custom_mode) if self.px4 else mode_name(msg.custom_mode)
                    if mode != state["mode"]:
                        self.modes.append((now, mode))
                    state.update(
                        mode=mode,
                        armed=bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED),
                        system_status=msg.system_status,
                    )
                elif t == "GLOBAL_POSITION_INT":
                    lat, lon = msg.lat / 1e7, msg.lon / 1e7
                    alt = msg.relative_alt / 1000.0
                    if system == self.target[0]:
                        self.max_alt = max(self.max_alt, alt)
                    north = east = 0.0
                    if home is not None:
                        north, east = local_ne(*home, lat, lon)
                    state.update(alt=alt, lat=lat, lon=lon, north=north, east=east)
                elif t == "LOCAL_POSITION_NED":
                    state.update(
                        x=msg.x, y=msg.y, z=msg.z, vx=msg.vx, vy=msg.vy, time_boot=msg.time_boot_ms / 1e3
                    )
                elif t == "POSITION_TARGET_LOCAL_NED":
                    state.update(target_vx=msg.vx, target_vy=msg.vy, target_frame=msg.coordinate_frame)
                elif t == "HOME_POSITION":
                    self.homes[system] = (msg.latitude / 1e7, msg.longitude / 1e7)
                elif t == "EXTENDED_SYS_STATE":
                    state["landed_state"] = msg.landed_state
                elif t == "SYS_STATUS":
                    state["voltage"] = msg.voltage_battery / 1000.0
                    bit = mav.MAV_SYS_STATUS_SENSOR_BATTERY
                    state["battery_healthy"] = bool(msg.onboard_control_sensors_health & bit)
                elif t == "BATTERY_STATUS":
                    state["battery_remaining"] = msg.battery_remaining
                elif t == "STATUSTEXT":
                    self.texts.append((now, msg.severity, msg.text))
                elif t == "PARAM_VALUE":
                    value = decode_param(msg.param_value, msg.param_type) if self.px4 else msg.param_value
                    self.params[msg.param_id] = (value, now)
                elif t == "COMMAND_ACK" and getattr(msg, "target_system", SYSTEM) in (0, SYSTEM):
                    self.acks[msg.command] = (msg.result, now)
                self.lock.notify_all()
            if t == "HEARTBEAT" and self.px4 and system not in self.slowed:
                self.slowed.add(system)
                self._slow_down(system)
            if t == "HEARTBEAT" and system not in self.homes:
                self.conn.mav.command_long_send(
                    system,
                    1,
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

    def _slow_down(self, system: int) -> None:
        """Ask PX4's GCS link for 10 Hz positions and none of its 50 Hz attitude, target and servo streams
        (px4-rc.mavlink starts them for a simulator's viewer): this helper's CPU goes to the flights."""
        for msg_id, hz in SLOW_STREAMS.items():
            interval = -1.0 if hz == 0 else 1e6 / hz
            self.conn.mav.command_long_send(
                system, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, interval, 0, 0, 0, 0, 0
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

    def set_param(self, name: str, value: float, integer: bool = False) -> dict[str, Any]:
        kind = mav.MAV_PARAM_TYPE_INT32 if integer else mav.MAV_PARAM_TYPE_REAL32
        wire = encode_param(value, kind) if self.px4 else value
        for _ in range(3):
            sent = time.monotonic()
            self.conn.mav.param_set_send(*self.target, name.encode(), wire, kind)

            def confirmed(sent: float = sent) -> bool:
                got = self.params.get(name)
                return got is not None and got[1] >= sent and abs(got[0] - value) <= 1e-3 * max(1, abs(value))

            if self._wait(confirmed, ACK_TIMEOUT):
                return {"ok": True}
        return {"ok": False, "error": f"{name} = {value} not confirmed: {self.params.get(name)}"}

    def get_param(self, name: str) -> dict[str, Any]:
        for _ in range(3):
            sent = time.monotonic()
            self.conn.mav.param_request_read_send(*self.target, name.encode(), -1)
            if self._wait(lambda sent=sent: self.params.get(name, (0.0, -1.0))[1] >= sent, ACK_TIMEOUT):
                return {"ok": True, "value": self.params[name][0]}
        return {"ok": False, "error": f"no PARAM_VALUE for {name}"}

    def set_mode(self, mode: str) -> dict[str, Any]:
        sent = time.monotonic()
        cmd = mav.MAV_CMD_DO_SET_MODE
        main, sub = px4_modes.COMMANDS[mode] if self.px4 else (COPTER_MODES[mode], 0)
        self.conn.mav.command_long_send(
            *self.target, cmd, 0, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub, 0, 0, 0, 0
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
            return self.set_param(req["name"], float(req["value"]), bool(req.get("int")))
        if op == "command":
            return self.command(int(req["command"]), [float(p) for p in req.get("params", [])])
        if op == "set_mode":
            return self.set_mode(req["mode"])
        if op == "get_param":
            return self.get_param(req["name"])
        with self.lock:
            if op == "state":
                system = req.get("system", self.target[0])
                state = self.states.get(system, self._blank())
                return {"ok": True, **state, "max_alt": self.max_alt, "home": system in self.homes}
            if op == "mark":
                self.modes, self.texts, self.max_alt = [], [], self.state["alt"]
                return {"ok": True}
            if op == "record":
                return {"ok": True, "modes": self.modes, "texts": self.texts, "max_alt": self.max_alt}
        return {"ok": False, "error": f"unknown op {op!r}"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("url")
    parser.add_argument("--stack", choices=("arducopter", "px4"), default="arducopter")
    parser.add_argument("--tcp-relay", metavar="LISTEN:UPSTREAM")
    parser.add_argument("--udp-relay", metavar="LISTEN:ADAPTER")
    args = parser.parse_args()
    out, sys.stdout = sys.stdout, sys.stderr  # pymavlink prints its retries: keep them off the replies
    relay: Relay | UdpRelay | None = None
    if args.tcp_relay:
        listen, upstream = (int(p) for p in args.tcp_relay.split(":"))
        relay = Relay(listen, upstream)
    elif args.udp_relay:
        listen, adapter = (int(p) for p in args.udp_relay.split(":"))
        relay = UdpRelay(listen, adapter)
    print(json.dumps({"ready": True}), file=out, flush=True)
    gcs: Gcs | None = None
    reply: dict[str, Any]
    for line in sys.stdin:
        try:
            req = json.loads(line)
            if req["op"] == "relay":
                if relay is None:
                    raise ValueError("started without a relay")
                relay.set_mode(req["mode"])
                reply = {"ok": True}
            elif req["op"] == "connect":
                gcs = gcs or Gcs(args.url, args.stack)
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
