"""The ArduCopter emulator's own knobs, each driven through the real pymavlink (tests/emulators/mavlink_vehicle.py).

The adapter tests lean on these behaving as ArduCopter does; here the less travelled ones are pinned:
parameter listing and types, the GCS failsafe's other actions and its recovery, the EKF failsafe to
ALT_HOLD, and a battery failsafe escalating from low to critical.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from antalate_lcm.autopilot import Frame
from antalate_lcm.autopilot.mavlink import MavlinkAutopilot
from tests.emulators.mavlink_vehicle import PARAMS, MavlinkVehicle
from tests.test_mavlink_adapter import FAST, fly, make_ap, state_until, vehicle_until


@pytest.fixture
def made() -> Iterator[list[Any]]:
    things: list[Any] = []
    yield things
    for thing in reversed(things):
        thing.close() if isinstance(thing, MavlinkAutopilot) else thing.stop()


def pair(
    made: list[Any], params: dict[str, float], **vehicle: Any
) -> tuple[MavlinkVehicle, MavlinkAutopilot]:
    v = MavlinkVehicle("127.0.0.1", 0, **{**FAST, "params": params, **vehicle}).start()
    made.append(v)
    ap = make_ap(v.udp_url)
    made.append(ap)
    ap.connect()
    return v, ap


def test_parameters_list_index_types_and_unknown_names(made: list[Any]) -> None:
    with pytest.raises(ValueError, match="unknown emulated parameter 'FS_GCS_ENABLED'"):
        MavlinkVehicle(params={"FS_GCS_ENABLED": 1})
    with pytest.raises(ValueError, match="gcs_sysid_param"):
        MavlinkVehicle(gcs_sysid_param="GCS_ID")
    v = MavlinkVehicle("127.0.0.1", 0, **FAST).start()
    made.append(v)
    conn = mavutil.mavlink_connection(v.udp_url, source_system=245, source_component=191)
    try:
        conn.mav.heartbeat_send(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        conn.mav.param_request_list_send(1, 1)
        seen: dict[str, Any] = {}
        deadline = time.monotonic() + 3
        while len(seen) < len(PARAMS) and time.monotonic() < deadline:
            msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
            if msg is not None:
                seen[msg.param_id] = msg
        assert set(seen) == set(PARAMS) and all(m.param_count == len(PARAMS) for m in seen.values())
        assert seen["FS_GCS_ENABLE"].param_type == mav2.MAV_PARAM_TYPE_INT8
        assert seen["BATT_LOW_VOLT"].param_value == pytest.approx(10.5)
        while conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.3) is not None:
            pass  # the rest of the list
        index = list(PARAMS).index("GUID_TIMEOUT")
        conn.mav.param_request_read_send(1, 1, b"", index)
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
        assert msg is not None and msg.param_id == "GUID_TIMEOUT" and msg.param_index == index
        conn.mav.param_set_send(1, 1, b"FENCE_ACTION", 3.7, mav2.MAV_PARAM_TYPE_INT8)  # an integer parameter
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
        assert msg is not None and msg.param_id == "FENCE_ACTION" and msg.param_value == 4.0
        conn.mav.param_set_send(1, 1, b"NO_SUCH_PARAM", 1.0, mav2.MAV_PARAM_TYPE_REAL32)
        assert (
            conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5) is None
        )  # no answer, as ArduPilot
    finally:
        conn.close()
    assert v.param("FENCE_ACTION") == 4.0


@pytest.mark.parametrize(("action", "mode"), [(5, "LAND"), (7, "BRAKE")])
def test_gcs_failsafe_actions_and_recovery(made: list[Any], action: int, mode: str) -> None:
    v, ap = pair(made, {"FS_GCS_ENABLE": action, "SYSID_MYGCS": 245, "FS_GCS_TIMEOUT": 1.0})
    fly(ap, v, alt=1.5)
    v.stop_heartbeats()  # the GCS's heartbeats no longer arrive (nor does anything else)
    vehicle_until(v, lambda s: s.mode == mode, 3)
    assert v.gcs_failsafe and ("GCS failsafe", mode) in v.failsafe_modes
    v.resume_heartbeats()
    assert v.wait_until(lambda s: not v.gcs_failsafe, 3) and "GCS Failsafe Cleared" in v.statustexts
    assert v.snapshot().mode == mode  # ArduCopter does not switch back by itself


def test_gcs_failsafe_disarms_on_the_ground(made: list[Any]) -> None:
    v, ap = pair(made, {"FS_GCS_ENABLE": 1, "SYSID_MYGCS": 245, "FS_GCS_TIMEOUT": 1.0})
    assert ap.arm() is True
    v.stop_heartbeats()
    vehicle_until(v, lambda s: not s.armed, 3)
    assert "GCS Failsafe - Disarming" in v.statustexts and v.snapshot().mode == "GUIDED"


def test_ekf_failsafe_to_alt_hold_and_back_to_health(made: list[Any]) -> None:
    v, ap = pair(made, {"FS_EKF_ACTION": 2})
    fly(ap, v, alt=1.5)
    v.fail_ekf()
    s = state_until(ap, lambda s: s.mode == "ALT_HOLD", 3)
    assert s.failsafe == "EKF failsafe" and not s.autonomous  # a pilot must fly ALT_HOLD
    v.fail_ekf(False)
    vehicle_until(v, lambda s: s.ekf_position_ok, 1)


def test_battery_failsafe_escalates_from_low_to_critical(made: list[Any]) -> None:
    v, ap = pair(
        made,
        {
            "BATT_LOW_VOLT": 10.5,
            "BATT_CRT_VOLT": 9.9,
            "BATT_LOW_TIMER": 1,
            "BATT_FS_LOW_ACT": 2,
            "BATT_FS_CRT_ACT": 1,
        },
        battery_drain=0.0,
    )
    fly(ap, v, alt=2.5)
    ap.set_velocity(0.0, 2.0, 0.0, 0.0, Frame.NED)
    v.set_voltage(10.3)
    s = state_until(ap, lambda s: s.mode == "RTL", 3)
    assert s.battery_warning == "low" and s.failsafe == "battery failsafe"
    v.set_voltage(9.8)
    s = state_until(ap, lambda s: s.mode == "LAND", 3)
    assert s.battery_warning == "critical" and s.failsafe == "battery failsafe"
    assert [m for f, m in v.failsafe_modes if f == "battery failsafe"] == ["RTL", "LAND"]
    v.set_voltage(None)  # the voltage recovers under less load: AP_BattMonitor keeps its failsafe
    time.sleep(1.2)
    assert ap.state().battery_warning == "critical" and v.voltage() > 12.0


def test_signature_checked_before_the_timestamp_as_ardupilot_does() -> None:
    """One forged frame with a later timestamp must not make the genuine stream look like replays."""
    from tests.emulators.mavlink_vehicle import _Peer

    key = bytes(range(32))
    peer = _Peer(1, 1, key=key)

    def signed(with_key: bytes, seconds_ahead: float) -> bytes:
        enc = mav2.MAVLink(None, srcSystem=245, srcComponent=191)
        enc.signing.secret_key, enc.signing.sign_outgoing, enc.signing.link_id = with_key, True, 7
        enc.signing.timestamp = int((time.time() - 1420070400 + seconds_ahead) * 1e5)
        return enc.heartbeat_encode(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(enc)

    assert [m.get_type() for m in peer.parse(signed(key, 0))] == ["HEARTBEAT"]
    assert peer.parse(signed(b"\x02" * 32, 3600)) == [] and peer.rejected == 1  # forged: a later timestamp
    assert [m.get_type() for m in peer.parse(signed(key, 1))] == ["HEARTBEAT"]  # genuine still accepted
    assert peer.parse(signed(key, 0.5)) == [] and peer.rejected == 2  # a replayed (older) one is not
