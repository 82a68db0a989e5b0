"""Graupner HoTT ESC telemetry, ROS-free: the receiver's request and the ESC sensor's reply.

HoTT runs on one wire, half duplex, at 19200 baud 8N1, idle high. The receiver (here: the
bridge firmware) sends the binary-mode request ``80 8C`` (ESC module); the ESC answers with a
45-byte frame whose last byte is the sum of the 44 before it, mod 256. Multi-byte fields are
little-endian. The layout below and its sources are in ``firmware/README.md`` (Betaflight's
``HOTT_AIRESC_MSG_t``, msrc's ``hott_sensor_airesc_t``, OpenTX's HoTT decoder), with what is
uncertain about a real Graupner ESC.

| offset | field | unit on the wire |
|---|---|---|
| 0 | start byte ``7C`` | |
| 1 | sensor id ``8C`` (ESC) | |
| 2 | warning beeps | |
| 3 | sensor text id ``C0`` | |
| 6 | input voltage (u16) | 0.1 V |
| 10 | used capacity (u16) | 10 mAh |
| 12 | ESC temperature (u8) | 1 °C, offset +20 |
| 14 | current (u16) | 0.1 A, unsigned |
| 18 | shaft speed (u16) | 10 rpm, unsigned |
| 43 | end byte ``7D`` | |
| 44 | checksum | sum of bytes 0..43 mod 256 |

The other bytes (minimum/maximum records, BEC, throttle, timing) are sent as 0.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

BAUD = 19200
"""Bit rate of the HoTT wire, bit/s (8N1, not inverted)."""
REQUEST_BINARY = 0x80
"""First request byte: binary (telemetry) mode."""
ESC_MODULE_ID = 0x8C
"""Second request byte and frame byte 1: the ESC module."""
ESC_TEXT_ID = 0xC0
"""Frame byte 3: the ESC's sensor text id."""
START_BYTE = 0x7C
END_BYTE = 0x7D
FRAME_LEN = 45
"""Bytes of an ESC reply, checksum included."""
REQUEST = bytes([REQUEST_BINARY, ESC_MODULE_ID])
"""What the receiver sends to poll the ESC."""

_VOLTAGE = 6
_CAPACITY = 10
_TEMPERATURE = 12
_CURRENT = 14
_RPM = 18
_END = 43
_TEMPERATURE_OFFSET = 20


@dataclass(frozen=True)
class HottEscFrame:
    """One HoTT ESC reply in physical units.

    Attributes
    ----------
    voltage_v : float
        Input (bus) voltage, V; 0.1 V on the wire, 0..6553.5 V.
    current_a : float
        Current, A, unsigned; 0.1 A on the wire, 0..6553.5 A.
    rpm : float
        Shaft speed, rpm, unsigned; 10 rpm on the wire, 0..655350 rpm.
    temperature_c : float
        ESC temperature, °C; whole degrees with an offset of 20 on the wire, -20..235 °C.
    capacity_mah : float
        Charge used since power-up, mAh; 10 mAh on the wire, 0..655350 mAh.
    """

    voltage_v: float
    current_a: float
    rpm: float
    temperature_c: float
    capacity_mah: float = 0.0


def checksum(data: bytes) -> int:
    """Sum of ``data`` mod 256: the last byte of a frame over the 44 before it."""
    return sum(data) & 0xFF


def _field(name: str, value: float, step: float, offset: float, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} must be a number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise ValueError(f"{name}={value} is not finite")
    raw = round(value / step + offset)
    if not 0 <= raw <= hi:
        lo_v, hi_v = -offset * step, (hi - offset) * step
        raise ValueError(f"{name}={value} outside {lo_v:g}..{hi_v:g}")
    return raw


def encode_esc_frame(frame: HottEscFrame) -> bytes:
    """Encode the ESC's 45-byte reply (what the ESC sends; used by the co-simulation and tests).

    Parameters
    ----------
    frame : HottEscFrame
        Values in physical units; rounded to the wire's resolution.

    Returns
    -------
    bytes
        The reply, checksum included.

    Raises
    ------
    ValueError
        If a value is not a finite number or does not fit its field after rounding.
    """
    data = bytearray(FRAME_LEN)
    data[0], data[1], data[3], data[_END] = START_BYTE, ESC_MODULE_ID, ESC_TEXT_ID, END_BYTE
    struct.pack_into("<H", data, _VOLTAGE, _field("voltage_v", frame.voltage_v, 0.1, 0, 0xFFFF))
    struct.pack_into(
        "<H", data, _CAPACITY, _field("capacity_mah", frame.capacity_mah, 10.0, 0, 0xFFFF)
    )
    data[_TEMPERATURE] = _field(
        "temperature_c", frame.temperature_c, 1.0, _TEMPERATURE_OFFSET, 0xFF
    )
    struct.pack_into("<H", data, _CURRENT, _field("current_a", frame.current_a, 0.1, 0, 0xFFFF))
    struct.pack_into("<H", data, _RPM, _field("rpm", frame.rpm, 10.0, 0, 0xFFFF))
    data[-1] = checksum(data[:-1])
    return bytes(data)


def decode_esc_frame(data: bytes) -> HottEscFrame:
    """Decode an ESC reply, checking its length, fixed bytes and checksum.

    Raises
    ------
    ValueError
        Naming the first check that failed.
    """
    if len(data) != FRAME_LEN:
        raise ValueError(f"a HoTT ESC frame has {FRAME_LEN} bytes, got {len(data)}")
    fixed = {0: START_BYTE, 1: ESC_MODULE_ID, 3: ESC_TEXT_ID, _END: END_BYTE}
    for offset, want in fixed.items():
        if data[offset] != want:
            raise ValueError(f"byte {offset} is {data[offset]:#04x}, expected {want:#04x}")
    if checksum(data[:-1]) != data[-1]:
        raise ValueError(f"checksum {data[-1]:#04x} != {checksum(data[:-1]):#04x}")
    (voltage,) = struct.unpack_from("<H", data, _VOLTAGE)
    (capacity,) = struct.unpack_from("<H", data, _CAPACITY)
    (current,) = struct.unpack_from("<H", data, _CURRENT)
    (rpm,) = struct.unpack_from("<H", data, _RPM)
    return HottEscFrame(
        voltage_v=voltage / 10,
        current_a=current / 10,
        rpm=float(rpm * 10),
        temperature_c=float(data[_TEMPERATURE] - _TEMPERATURE_OFFSET),
        capacity_mah=float(capacity * 10),
    )
