"""A Crazyradio dongle as pyusb shows it to cflib, carrying CRTP to `CrazyflieEmulator` s by radio address.

cflib's ``radio://`` link (cflib 0.1.34 ``crtp/radiodriver.py``) is the one Crazyflies fly on, and it
has a failure path the ``udp://`` driver lacks: every outgoing packet must be acknowledged by the
Crazyflie's radio, the driver resends an unacknowledged one, and after ``_nr_of_retries`` (100) in a
row it calls the link-error callback with "Too many packets lost" and the link is gone
(``Crazyflie._link_error_cb`` closes it). Replies only travel in acknowledgements: the Crazyflie
puts its next queued packet in the ack payload of whatever the host sent, so the host polls with
null packets (``0xFF``) when it has nothing to say.

This module stands in for the USB device (``cflib.drivers.crazyradio.Crazyradio`` finds it through
``_find_devices``, which `install` replaces), not for cflib: cflib's ``Crazyradio``, its shared-radio
thread, ``RadioDriver`` and ``Crazyflie`` all run unchanged. What the dongle does, from the
Crazyradio USB protocol cflib speaks (``drivers/crazyradio.py``): vendor control transfers set the
channel, address, data rate, power, ARC and ARD (answered, no effect here); a bulk write to
endpoint 1 is one radio packet; the bulk read from 0x81 that follows is the result -- byte 0 the
status (bit 0 "acknowledged", bits 4-7 the retransmissions), then the ack payload. A Crazyflie that
is silent, powered off or on another channel/address acknowledges nothing: status 0, after
``no_ack_s`` (the dongle's ``ARC`` = 3 retransmissions ``_nr_of_arc_retries``, a few hundred
microseconds each, plus the USB round trip), so cflib gives up after about 0.2 s of silence, as on
a real radio. Safelink (the ``0xFF 0x05 0x01`` handshake) is not answered, so cflib runs without it
(``needs_resending``), as with older Crazyflie radio firmware.
"""

from __future__ import annotations

import array
import threading
import time
from collections.abc import Callable
from typing import Any

from tests.emulators.crazyflie_emulator import CrazyflieEmulator

SET_RADIO_CHANNEL, SET_RADIO_ADDRESS = 0x01, 0x02  # cflib drivers/crazyradio.py vendor requests
DEFAULT_ADDRESS = (0xE7, 0xE7, 0xE7, 0xE7, 0xE7)


class _NoContext:
    """pyusb's device context: ``usb.util.dispose_resources`` (cflib's ``Crazyradio.close``) calls it."""

    def dispose(self, _device: Any) -> None:
        return None


class Crazyradio:
    """The dongle: `add` puts an emulated Crazyflie on a channel and address and returns its URI."""

    bcdDevice = 0x0501  # firmware 5.1: cflib's "version" 5.1 (>= 0.4, so ARC and ACK are set)
    serial_number = "EMULATED"

    def __init__(self, no_ack_s: float = 0.002) -> None:
        self.no_ack_s = no_ack_s
        self._ctx = _NoContext()
        self._lock = threading.Lock()
        self._crazyflies: dict[tuple[int, tuple[int, ...]], CrazyflieEmulator] = {}
        self._channel = 2
        self._address: tuple[int, ...] = DEFAULT_ADDRESS
        self._out = b""
        self.lost = 0  # packets nobody acknowledged

    def add(
        self, emulator: CrazyflieEmulator, channel: int = 80, address: tuple[int, ...] = DEFAULT_ADDRESS
    ) -> str:
        with self._lock:
            self._crazyflies[(channel, tuple(address))] = emulator
        emulator.radio_uri = f"radio://0/{channel}/2M/{''.join(f'{b:02X}' for b in address)}"
        return emulator.radio_uri

    # ------------------------------------------------------------------ what cflib calls (pyusb's Device)
    def set_configuration(self, _configuration: int | None = None) -> None:
        return None

    def reset(self) -> None:
        return None

    def ctrl_transfer(
        self,
        bm_request_type: int,
        b_request: int,
        wValue: int = 0,  # noqa: N803 - pyusb's keyword names
        wIndex: int = 0,  # noqa: N803
        data_or_wLength: Any = None,  # noqa: N803
        timeout: int | None = None,
    ) -> Any:
        if bm_request_type & 0x80:  # a read: nothing to report
            return array.array("B", bytes(int(data_or_wLength or 0)))
        with self._lock:
            if b_request == SET_RADIO_CHANNEL:
                self._channel = wValue
            elif b_request == SET_RADIO_ADDRESS:
                self._address = tuple(data_or_wLength)
        return 0

    def write(self, endpoint: int, data: Any, timeout: int | None = None) -> int:
        self._out = bytes(data)
        return len(self._out)

    def read(self, endpoint: int, size: int, timeout: int | None = None) -> array.array[int]:
        with self._lock:
            emulator = self._crazyflies.get((self._channel, self._address))
        ack = emulator.radio_exchange(self._out) if emulator is not None else None
        if ack is None:
            self.lost += 1
            time.sleep(self.no_ack_s)
            return array.array("B", [0])
        return array.array("B", [0x01]) + array.array("B", ack)


def install(dongle: Crazyradio) -> Callable[[], None]:
    """cflib finds `dongle` as Crazyradio 0 (and only it) until the returned function is called."""
    import cflib.drivers.crazyradio as driver
    from cflib.crtp.radiodriver import RadioManager

    def forget_shared_radio() -> None:  # cflib keeps one per dongle index for the process
        if RadioManager._radios:
            RadioManager.remove(0)

    original = driver._find_devices
    forget_shared_radio()
    driver._find_devices = lambda serial=None: [dongle]

    def uninstall() -> None:
        driver._find_devices = original
        forget_shared_radio()

    return uninstall
