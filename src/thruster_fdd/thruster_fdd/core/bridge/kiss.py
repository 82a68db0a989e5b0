"""KISS / BLHeli_32 ESC telemetry: the de-facto 10-byte frame with a CRC-8 and no sync bytes,
for a bridge that forwards an ESC's own telemetry (docs/protocol.md). Telemetry only.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from thruster_fdd.core.bridge.crc import crc8_kiss
from thruster_fdd.core.bridge.stuck import StuckRun
from thruster_fdd.core.bridge.tfdd import DecoderStats, checked_int, scaled_int

KISS_FRAME_LEN = 10
"""Bytes per KISS telemetry frame, CRC included."""


DEFAULT_POLE_PAIRS = 7
"""Motor pole pairs of the T100/T200 (14 poles): mechanical rpm = eRPM / 7."""


_KISS = struct.Struct(">BHHHH")


_STUCK_WINDOWS = frozenset({bytes(KISS_FRAME_LEN), b"\xff" * KISS_FRAME_LEN})


@dataclass(frozen=True)
class KissFrame:
    """One KISS / BLHeli_32 telemetry frame in physical units.

    Attributes
    ----------
    temperature_c : float
        ESC temperature in °C, whole degrees 0..255 on the wire.
    voltage_v : float
        Bus voltage in V (0.01 V resolution, 0..655.35 V).
    current_a : float
        Current in A, unsigned (0.01 A resolution, 0..655.35 A).
    consumption_mah : int
        Charge drawn since ESC power-up in mAh, 0..65535.
    rpm : float
        Mechanical shaft speed in rpm, unsigned: eRPM / pole pairs, with eRPM sent in steps of
        100 (about 14.3 rpm for 7 pole pairs).
    """

    temperature_c: float
    voltage_v: float
    current_a: float
    consumption_mah: int
    rpm: float


def _check_pole_pairs(pole_pairs: int) -> int:
    return checked_int("pole_pairs", pole_pairs, 1, 255)


def encode_kiss(frame: KissFrame, pole_pairs: int = DEFAULT_POLE_PAIRS) -> bytes:
    """Encode a KISS telemetry frame (what a BLHeli_32/KISS ESC sends).

    Parameters
    ----------
    frame : KissFrame
        Sample in physical units; rounded to the wire resolution.
    pole_pairs : int
        Motor pole pairs, 1..255, to turn mechanical rpm into eRPM.

    Returns
    -------
    bytes
        The 10-byte frame.

    Raises
    ------
    ValueError
        If a value is not finite, negative, or does not fit its field.
    """
    _check_pole_pairs(pole_pairs)
    payload = _KISS.pack(
        scaled_int("temperature_c", frame.temperature_c, 1, 0, 0xFF),
        scaled_int("voltage_v", frame.voltage_v, 100, 0, 0xFFFF),
        scaled_int("current_a", frame.current_a, 100, 0, 0xFFFF),
        checked_int("consumption_mah", frame.consumption_mah, 0, 0xFFFF),
        scaled_int("rpm", frame.rpm, pole_pairs / 100, 0, 0xFFFF),
    )
    return payload + bytes([crc8_kiss(payload)])


class KissDecoder:
    """Streaming KISS telemetry decoder; frame boundaries are found by the CRC alone.

    At each position the next 10 bytes are tried as a frame; while the CRC fails the decoder
    slides one byte. An 8-bit CRC passes on about 1 in 256 misaligned windows, so after noise a
    false frame can be accepted: check samples with ``check_telemetry`` and prefer tfdd. Ten
    bytes of one repeated 0x00 or 0xFF (a stuck line, ``core.bridge.stuck``) are never a frame.

    Parameters
    ----------
    pole_pairs : int
        Motor pole pairs, 1..255 (7 for T100/T200).

    Raises
    ------
    ValueError
        If ``pole_pairs`` is outside 1..255.
    """

    def __init__(self, pole_pairs: int = DEFAULT_POLE_PAIRS) -> None:
        self._pole_pairs = _check_pole_pairs(pole_pairs)
        self._buf = bytearray()
        self._locked = False
        self._counts = {name: 0 for name in DecoderStats.__dataclass_fields__}
        self._stuck = StuckRun()

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a frame (at most ``KISS_FRAME_LEN - 1``)."""
        return len(self._buf)

    def stats(self) -> DecoderStats:
        """Return a snapshot of the counters (the tfdd-only ones stay 0)."""
        return DecoderStats(**self._counts)

    def feed(self, data: bytes) -> list[KissFrame]:
        """Consume received bytes; never raises on any content.

        Parameters
        ----------
        data : bytes
            The next bytes from the serial port, any length.

        Returns
        -------
        list of KissFrame
            Frames completed by these bytes, in stream order.
        """
        out: list[KissFrame] = []
        counts = self._counts
        counts["bytes_received"] += len(data)
        self._stuck.feed(data)
        counts["stuck_low_bytes"] = self._stuck.low_bytes
        counts["stuck_high_bytes"] = self._stuck.high_bytes
        buf = self._buf
        buf += data
        pos = 0
        while len(buf) - pos >= KISS_FRAME_LEN:
            window = bytes(buf[pos : pos + KISS_FRAME_LEN])
            # Ten 0x00 bytes pass the CRC-8 (0 V, 0 A, 0 rpm): a line stuck low, not a frame.
            if crc8_kiss(window[:-1]) == window[-1] and window not in _STUCK_WINDOWS:
                temp, volt, curr, mah, erpm_100 = _KISS.unpack(window[:-1])
                rpm = erpm_100 * 100 / self._pole_pairs
                out.append(KissFrame(float(temp), volt / 100, curr / 100, mah, rpm))
                counts["frames_ok"] += 1
                self._locked = True
                pos += KISS_FRAME_LEN
                continue
            # Only a failure where a frame was due counts as an error; sliding through noise
            # is garbage.
            if self._locked:
                counts["crc_errors"] += 1
                counts["resyncs"] += 1
                self._locked = False
            counts["garbage_bytes"] += 1
            pos += 1
        del buf[:pos]
        return out
