"""Serial bridge protocols between the ESC driver and the thruster microcontroller, ROS-free.

Two wire formats (layouts, units and error rules in ``docs/protocol.md``):

* **tfdd v1**, the project's bridge protocol: sync bytes, version, type, sequence number, length,
  payload and a CRC-16/CCITT-FALSE. Telemetry goes bridge -> host, commands host -> bridge.
* **KISS / BLHeli_32 ESC telemetry**: the de-facto 10-byte frame with a CRC-8 and no sync bytes,
  for a bridge that forwards an ESC's own telemetry.

Encoders are pure functions that raise ``ValueError`` on values the wire cannot carry. The
decoders are the only stateful objects: they take arbitrary byte chunks, never raise, keep a
bounded buffer and count what went wrong.
"""

from __future__ import annotations

import binascii
import enum
import math
import struct
from dataclasses import dataclass
from typing import Literal

# --------------------------------------------------------------------------------------------
# CRCs
# --------------------------------------------------------------------------------------------


def crc16_ccitt_false(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, not reflected, xorout 0).

    Parameters
    ----------
    data : bytes
        Bytes to check.

    Returns
    -------
    int
        The CRC, 0..0xFFFF (0x29B1 for ``b"123456789"``).
    """
    # binascii.crc_hqx is this exact CRC (poly 0x1021, MSB first) given init 0xFFFF.
    return binascii.crc_hqx(data, 0xFFFF)


def _crc8_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_CRC8_TABLE = _crc8_table(0x07)


def crc8_kiss(data: bytes) -> int:
    """CRC-8 of KISS / BLHeli_32 telemetry (poly 0x07, init 0, MSB first: CRC-8/SMBUS).

    Equal to the ``get_crc8`` / ``update_crc8`` pair of the KISS ESC telemetry documentation and
    Betaflight.

    Parameters
    ----------
    data : bytes
        Bytes to check.

    Returns
    -------
    int
        The CRC, 0..0xFF (0xF4 for ``b"123456789"``).
    """
    crc = 0
    for byte in data:
        crc = _CRC8_TABLE[crc ^ byte]
    return crc


# --------------------------------------------------------------------------------------------
# tfdd v1: constants and messages
# --------------------------------------------------------------------------------------------

SYNC = b"\xa5\x5a"
"""The two sync bytes that start every tfdd frame."""
PROTOCOL_VERSION = 1
"""Value of the version byte this module writes and accepts."""
HEADER_LEN = 7
"""Sync (2) + version (1) + type (1) + sequence (2) + payload length (1), in bytes."""
CRC_LEN = 2
MAX_PAYLOAD_LEN = 32
"""Longest payload any v1 frame may declare; a larger length byte marks a false sync."""
MAX_FRAME_LEN = HEADER_LEN + MAX_PAYLOAD_LEN + CRC_LEN
"""Longest possible tfdd frame, in bytes; also the decoder's buffer bound between feeds."""
SEQ_MODULUS = 1 << 16
"""Sequence numbers are u16 and wrap from 65535 to 0."""


class MsgType(enum.IntEnum):
    """Values of the tfdd type byte."""

    TELEMETRY = 0x01
    """Bridge -> host: one telemetry sample (``TelemetryFrame``)."""
    COMMAND = 0x02
    """Host -> bridge: pulse to apply and watchdog timeout (``CommandFrame``)."""
    VERSION_QUERY = 0x03
    """Host -> bridge: ask for the firmware version (``VersionQuery``, empty payload)."""
    VERSION = 0x04
    """Bridge -> host: firmware version (``VersionFrame``)."""


class StatusFlag(enum.IntFlag):
    """Bits of the telemetry status byte, set by the bridge firmware."""

    ESC_TIMEOUT = 0x01
    """No valid command within the command timeout: the bridge applies the neutral pulse."""
    ADC_FAULT = 0x02
    """Voltage/current ADC readings are unreliable (out of rails, conversion timeout)."""
    RPM_FAULT = 0x04
    """No rpm signal from the ESC although it is driven: rpm is unreliable."""
    CMD_CLAMPED = 0x08
    """The commanded pulse was outside the bridge's limits and was clamped."""
    RESET = 0x10
    """First telemetry after a microcontroller reset (sequence and timestamp restart)."""


PWM_COMMAND_MIN_US = 1000
"""Smallest pulse a command may ask for, in microseconds (RC servo range)."""
PWM_COMMAND_MAX_US = 2000
"""Largest pulse a command may ask for, in microseconds."""

_TELEMETRY = struct.Struct("<IHHhihB")
_COMMAND = struct.Struct("<HH")
_VERSION = struct.Struct("<BBB")
_PAYLOAD_LEN = {
    MsgType.TELEMETRY: _TELEMETRY.size,
    MsgType.COMMAND: _COMMAND.size,
    MsgType.VERSION_QUERY: 0,
    MsgType.VERSION: _VERSION.size,
}


@dataclass(frozen=True)
class TelemetryFrame:
    """One telemetry sample sent by the bridge, in physical units.

    Attributes
    ----------
    timestamp_us : int
        Microcontroller clock at sampling, in µs; u32 that wraps about every 71.6 min.
    pwm_us : int
        Pulse width actually applied to the ESC, in µs.
    voltage_v : float
        Bus voltage in V (0.01 V resolution on the wire, 0..655.35 V).
    current_a : float
        Bus current in A, signed (0.01 A resolution, -327.68..327.67 A).
    rpm : float
        Shaft speed in rpm, signed (negative in reverse); whole rpm on the wire.
    temperature_c : float
        ESC/bridge temperature in °C (0.01 °C resolution, -327.68..327.67 °C).
    status : int
        ``StatusFlag`` bits, 0..255; unknown bits are kept.
    """

    timestamp_us: int
    pwm_us: int
    voltage_v: float
    current_a: float
    rpm: float
    temperature_c: float
    status: int = 0


@dataclass(frozen=True)
class CommandFrame:
    """A command from the host to the bridge.

    Attributes
    ----------
    pwm_us : int
        Pulse width to apply to the ESC, in µs, ``PWM_COMMAND_MIN_US..PWM_COMMAND_MAX_US``.
    timeout_ms : int
        Bridge watchdog in ms, 1..65535: with no new command for this long the bridge applies
        the neutral pulse and sets ``StatusFlag.ESC_TIMEOUT``.
    """

    pwm_us: int
    timeout_ms: int


@dataclass(frozen=True)
class VersionQuery:
    """Host -> bridge request for a ``VersionFrame`` (no fields, empty payload)."""


@dataclass(frozen=True)
class VersionFrame:
    """The bridge firmware's version, sent in reply to a ``VersionQuery``.

    Attributes
    ----------
    major, minor, patch : int
        Firmware version numbers, 0..255 each.
    """

    major: int
    minor: int
    patch: int


Message = TelemetryFrame | CommandFrame | VersionQuery | VersionFrame


@dataclass(frozen=True)
class DecodedFrame:
    """A tfdd frame that passed the CRC and all header checks.

    Attributes
    ----------
    seq : int
        Sequence number, 0..65535.
    message : Message
        The decoded payload.
    """

    seq: int
    message: Message


@dataclass(frozen=True)
class DecoderStats:
    """Counters of a decoder since it was created (a snapshot; all counts, never reset).

    Attributes
    ----------
    bytes_received : int
        Bytes passed to ``feed``.
    frames_ok : int
        Frames returned.
    crc_errors : int
        Complete candidate frames whose CRC failed (tfdd: with no sync inside them; KISS: a
        failure where a frame was expected right after a good one).
    garbage_bytes : int
        Bytes discarded without being part of a returned frame.
    resyncs : int
        Times the decoder gave up a candidate frame boundary and searched again.
    truncated : int
        tfdd only: candidates abandoned because their length byte is impossible (above
        ``MAX_PAYLOAD_LEN`` or not the length of their type), or because a new sync appeared
        inside them (their CRC failed with a sync inside, or a complete valid frame starts
        behind them before they are complete).
    unknown_type : int
        tfdd only: frames with a good CRC but an unknown type byte (skipped).
    bad_version : int
        tfdd only: syncs followed by a version byte other than ``PROTOCOL_VERSION`` (a bridge
        speaking another version, or noise); such a frame's layout is unknown, so it is skipped
        like a false sync.
    """

    bytes_received: int = 0
    frames_ok: int = 0
    crc_errors: int = 0
    garbage_bytes: int = 0
    resyncs: int = 0
    truncated: int = 0
    unknown_type: int = 0
    bad_version: int = 0


# --------------------------------------------------------------------------------------------
# tfdd v1: encoders
# --------------------------------------------------------------------------------------------


def _check_int(name: str, value: int, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} must be an int, got {type(value).__name__}")
    if not lo <= value <= hi:
        raise ValueError(f"{name}={value} outside {lo}..{hi}")
    return value


def _scaled(name: str, value: float, scale: float, lo: int, hi: int) -> int:
    """Quantise ``value * scale`` to the nearest integer, refusing what the field cannot hold."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} must be a number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise ValueError(f"{name}={value} is not finite")
    raw = round(value * scale)
    if not lo <= raw <= hi:
        raise ValueError(f"{name}={value} outside {lo / scale:g}..{hi / scale:g}")
    return raw


def _frame(msg_type: MsgType, seq: int, payload: bytes) -> bytes:
    _check_int("seq", seq, 0, SEQ_MODULUS - 1)
    body = struct.pack("<BBHB", PROTOCOL_VERSION, msg_type, seq, len(payload)) + payload
    return SYNC + body + crc16_ccitt_false(body).to_bytes(2, "little")


def encode_telemetry(frame: TelemetryFrame, seq: int) -> bytes:
    """Encode a telemetry frame (what the bridge firmware sends; used by simulators and tests).

    Parameters
    ----------
    frame : TelemetryFrame
        Sample in physical units; floats are rounded to the wire resolution.
    seq : int
        Sequence number, 0..65535.

    Returns
    -------
    bytes
        The complete frame, ``HEADER_LEN + 17 + CRC_LEN`` = 26 bytes.

    Raises
    ------
    ValueError
        If a value is not finite, has the wrong type, or does not fit its wire field.
    """
    payload = _TELEMETRY.pack(
        _check_int("timestamp_us", frame.timestamp_us, 0, 0xFFFF_FFFF),
        _check_int("pwm_us", frame.pwm_us, 0, 0xFFFF),
        _scaled("voltage_v", frame.voltage_v, 100, 0, 0xFFFF),
        _scaled("current_a", frame.current_a, 100, -0x8000, 0x7FFF),
        _scaled("rpm", frame.rpm, 1, -0x8000_0000, 0x7FFF_FFFF),
        _scaled("temperature_c", frame.temperature_c, 100, -0x8000, 0x7FFF),
        _check_int("status", frame.status, 0, 0xFF),
    )
    return _frame(MsgType.TELEMETRY, seq, payload)


def encode_command(frame: CommandFrame, seq: int) -> bytes:
    """Encode a host -> bridge command.

    Parameters
    ----------
    frame : CommandFrame
        Pulse in µs and bridge watchdog timeout in ms.
    seq : int
        Sequence number, 0..65535.

    Returns
    -------
    bytes
        The complete frame, 13 bytes.

    Raises
    ------
    ValueError
        If the pulse is outside ``PWM_COMMAND_MIN_US..PWM_COMMAND_MAX_US`` or the timeout
        outside 1..65535 ms (0 would disable the bridge's watchdog).
    """
    payload = _COMMAND.pack(
        _check_int("pwm_us", frame.pwm_us, PWM_COMMAND_MIN_US, PWM_COMMAND_MAX_US),
        _check_int("timeout_ms", frame.timeout_ms, 1, 0xFFFF),
    )
    return _frame(MsgType.COMMAND, seq, payload)


def encode_version_query(seq: int) -> bytes:
    """Encode a host -> bridge version query (9 bytes; empty payload).

    Raises
    ------
    ValueError
        If ``seq`` is outside 0..65535.
    """
    return _frame(MsgType.VERSION_QUERY, seq, b"")


def encode_version(frame: VersionFrame, seq: int) -> bytes:
    """Encode the bridge's reply to a version query (12 bytes).

    Raises
    ------
    ValueError
        If a version number is outside 0..255 or ``seq`` outside 0..65535.
    """
    payload = _VERSION.pack(
        _check_int("major", frame.major, 0, 0xFF),
        _check_int("minor", frame.minor, 0, 0xFF),
        _check_int("patch", frame.patch, 0, 0xFF),
    )
    return _frame(MsgType.VERSION, seq, payload)


def _decode_payload(msg_type: MsgType, payload: bytes) -> Message:
    if msg_type is MsgType.TELEMETRY:
        t_us, pwm, volt, curr, rpm, temp, status = _TELEMETRY.unpack(payload)
        return TelemetryFrame(t_us, pwm, volt / 100, curr / 100, float(rpm), temp / 100, status)
    if msg_type is MsgType.COMMAND:
        return CommandFrame(*_COMMAND.unpack(payload))
    if msg_type is MsgType.VERSION:
        return VersionFrame(*_VERSION.unpack(payload))
    return VersionQuery()


# --------------------------------------------------------------------------------------------
# tfdd v1: streaming decoder
# --------------------------------------------------------------------------------------------


class FrameDecoder:
    """Streaming tfdd decoder: feed it serial bytes in any chunking, get whole frames back.

    Search for ``SYNC``; refuse a header with another version or an impossible length; wait for
    the whole frame, unless a complete valid frame already starts behind it; check the CRC. On
    every rejection only the first sync byte is dropped before searching again, so a real frame
    that starts inside a false or truncated one is still found. The buffer holds at most
    ``MAX_FRAME_LEN`` bytes between calls, whatever arrives.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._counts = {name: 0 for name in DecoderStats.__dataclass_fields__}

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a frame (at most ``MAX_FRAME_LEN``)."""
        return len(self._buf)

    def stats(self) -> DecoderStats:
        """Return a snapshot of the counters."""
        return DecoderStats(**self._counts)

    def feed(self, data: bytes) -> list[DecodedFrame]:
        """Consume received bytes; never raises on any content.

        Parameters
        ----------
        data : bytes
            The next bytes from the serial port, any length.

        Returns
        -------
        list of DecodedFrame
            Frames completed by these bytes, in stream order.
        """
        out: list[DecodedFrame] = []
        self._counts["bytes_received"] += len(data)
        # Slices keep the buffer bounded even when one call brings megabytes of noise.
        for start in range(0, len(data), MAX_FRAME_LEN):
            self._buf += data[start : start + MAX_FRAME_LEN]
            self._drain(out)
        return out

    def _drop(self, n: int) -> None:
        self._counts["garbage_bytes"] += n
        del self._buf[:n]

    def _resync(self, reason: str) -> None:
        self._counts[reason] += 1
        self._counts["resyncs"] += 1
        self._drop(1)

    def _reject_header(self, pos: int) -> str | None:
        """Name the counter for a header at ``pos`` that cannot start a v1 frame, else None."""
        buf = self._buf
        if buf[pos + 2] != PROTOCOL_VERSION:
            return "bad_version"
        length = buf[pos + 6]
        if length > MAX_PAYLOAD_LEN or _PAYLOAD_LEN.get(buf[pos + 3], length) != length:
            return "truncated"
        return None

    def _crc_ok(self, pos: int, end: int) -> bool:
        buf = self._buf
        crc = int.from_bytes(buf[end - CRC_LEN : end], "little")
        return crc16_ccitt_false(bytes(buf[pos + 2 : end - CRC_LEN])) == crc

    def _later_frame(self) -> int:
        """Offset of a complete, valid frame after the candidate at 0, or -1."""
        buf = self._buf
        pos = buf.find(SYNC, 2)
        while 0 <= pos <= len(buf) - HEADER_LEN:
            end = pos + HEADER_LEN + buf[pos + 6] + CRC_LEN
            if self._reject_header(pos) is None and end <= len(buf) and self._crc_ok(pos, end):
                return pos
            pos = buf.find(SYNC, pos + 1)
        return -1

    def _drain(self, out: list[DecodedFrame]) -> None:
        buf = self._buf
        while buf:
            pos = buf.find(SYNC)
            if pos < 0:
                # A trailing first sync byte may be completed by the next chunk.
                self._drop(len(buf) - (buf[-1] == SYNC[0]))
                return
            self._drop(pos)
            if len(buf) < HEADER_LEN:
                return
            reason = self._reject_header(0)
            if reason is not None:
                self._resync(reason)
                continue
            end = HEADER_LEN + buf[6] + CRC_LEN
            if len(buf) < end:
                # A whole valid frame behind this sync means the candidate was cut short.
                later = self._later_frame()
                if later < 0:
                    return
                self._counts["truncated"] += 1
                self._counts["resyncs"] += 1
                self._drop(later)
                continue
            if not self._crc_ok(0, end):
                self._resync("truncated" if buf.find(SYNC, 2, end) >= 0 else "crc_errors")
                continue
            type_byte, seq = buf[3], int.from_bytes(buf[4:6], "little")
            payload = bytes(buf[HEADER_LEN : end - CRC_LEN])
            # The CRC proves the framing, so the whole frame goes even if its type is unknown.
            del buf[:end]
            if type_byte in _PAYLOAD_LEN:
                self._counts["frames_ok"] += 1
                out.append(DecodedFrame(seq, _decode_payload(MsgType(type_byte), payload)))
            else:
                self._counts["unknown_type"] += 1


# --------------------------------------------------------------------------------------------
# Sequence numbers
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SeqCheck:
    """How a received sequence number relates to the previous one.

    Attributes
    ----------
    status : {"ok", "duplicate", "lost", "reordered"}
        ``ok``: the next number; ``duplicate``: the same number again; ``lost``: ``lost``
        numbers were skipped; ``reordered``: older than the previous one (also what a bridge
        reset to 0 looks like).
    lost : int
        Number of frames missing between the two, > 0 only when ``status == "lost"``.
    """

    status: Literal["ok", "duplicate", "lost", "reordered"]
    lost: int = 0


def classify_seq(prev: int, new: int) -> SeqCheck:
    """Classify a sequence number against the previous one, with u16 wrap-around.

    Serial-number arithmetic (RFC 1982): a forward distance below half the range is progress,
    anything else is a step back. The caller should keep the newest number seen, i.e. update
    ``prev`` only on ``ok`` and ``lost``.

    Parameters
    ----------
    prev, new : int
        Previous and new sequence numbers, 0..65535.

    Returns
    -------
    SeqCheck
        The classification.

    Raises
    ------
    ValueError
        If either number is outside 0..65535.
    """
    _check_int("prev", prev, 0, SEQ_MODULUS - 1)
    _check_int("new", new, 0, SEQ_MODULUS - 1)
    delta = (new - prev) % SEQ_MODULUS
    if delta == 0:
        return SeqCheck("duplicate")
    if delta == 1:
        return SeqCheck("ok")
    if delta < SEQ_MODULUS // 2:
        return SeqCheck("lost", delta - 1)
    return SeqCheck("reordered")


# --------------------------------------------------------------------------------------------
# KISS / BLHeli_32 ESC telemetry
# --------------------------------------------------------------------------------------------

KISS_FRAME_LEN = 10
"""Bytes per KISS telemetry frame, CRC included."""
DEFAULT_POLE_PAIRS = 7
"""Motor pole pairs of the T100/T200 (14 poles): mechanical rpm = eRPM / 7."""

_KISS = struct.Struct(">BHHHH")


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
    return _check_int("pole_pairs", pole_pairs, 1, 255)


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
        _scaled("temperature_c", frame.temperature_c, 1, 0, 0xFF),
        _scaled("voltage_v", frame.voltage_v, 100, 0, 0xFFFF),
        _scaled("current_a", frame.current_a, 100, 0, 0xFFFF),
        _check_int("consumption_mah", frame.consumption_mah, 0, 0xFFFF),
        _scaled("rpm", frame.rpm, pole_pairs / 100, 0, 0xFFFF),
    )
    return payload + bytes([crc8_kiss(payload)])


class KissDecoder:
    """Streaming KISS telemetry decoder; frame boundaries are found by the CRC alone.

    At each position the next 10 bytes are tried as a frame; while the CRC fails the decoder
    slides one byte. An 8-bit CRC passes on about 1 in 256 misaligned windows, so after noise a
    false frame can be accepted: check samples with ``check_telemetry`` and prefer tfdd.

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
        buf = self._buf
        buf += data
        pos = 0
        while len(buf) - pos >= KISS_FRAME_LEN:
            window = bytes(buf[pos : pos + KISS_FRAME_LEN])
            if crc8_kiss(window[:-1]) == window[-1]:
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


# --------------------------------------------------------------------------------------------
# Physical plausibility
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TelemetrySample:
    """Telemetry fields common to both protocols; None where the protocol lacks the field.

    Attributes
    ----------
    voltage_v, current_a, rpm, temperature_c : float or None
        V, A (signed in tfdd, unsigned in KISS), rpm (signed in tfdd, unsigned in KISS), °C.
    pwm_us : int or None
        Pulse applied by the bridge in µs (tfdd only).
    timestamp_us : int or None
        Microcontroller clock in µs (tfdd only).
    status : int or None
        ``StatusFlag`` bits (tfdd only).
    consumption_mah : int or None
        Charge drawn since power-up in mAh (KISS only).
    """

    voltage_v: float | None
    current_a: float | None
    rpm: float | None
    temperature_c: float | None
    pwm_us: int | None = None
    timestamp_us: int | None = None
    status: int | None = None
    consumption_mah: int | None = None


def to_sample(frame: TelemetryFrame | KissFrame) -> TelemetrySample:
    """Map either protocol's telemetry onto the common physical fields."""
    if isinstance(frame, KissFrame):
        return TelemetrySample(
            frame.voltage_v,
            frame.current_a,
            frame.rpm,
            frame.temperature_c,
            consumption_mah=frame.consumption_mah,
        )
    return TelemetrySample(
        frame.voltage_v,
        frame.current_a,
        frame.rpm,
        frame.temperature_c,
        pwm_us=frame.pwm_us,
        timestamp_us=frame.timestamp_us,
        status=frame.status,
    )


PLAUSIBLE_LIMITS: dict[str, tuple[float, float]] = {
    "voltage_v": (0.0, 60.0),
    "current_a": (-60.0, 60.0),
    "rpm": (-10_000.0, 10_000.0),
    "temperature_c": (-20.0, 125.0),
    "pwm_us": (900.0, 2100.0),
}
"""Inclusive (low, high) bounds, in each field's unit, outside which a sample is implausible
for a T100/T200 on a <= 60 V bus (about 3x the T200's 20 V / 35 A / 5000 rpm envelope)."""

_FAULT_FLAGS = (StatusFlag.ADC_FAULT, StatusFlag.RPM_FAULT)


def check_telemetry(frame: TelemetryFrame | KissFrame | TelemetrySample) -> tuple[str, ...]:
    """List why a telemetry sample is physically implausible.

    Parameters
    ----------
    frame : TelemetryFrame, KissFrame or TelemetrySample
        The sample; fields that are None are not checked.

    Returns
    -------
    tuple of str
        One human-readable problem per offending field or fault flag; empty when plausible.
    """
    sample = frame if isinstance(frame, TelemetrySample) else to_sample(frame)
    problems: list[str] = []
    for name, (lo, hi) in PLAUSIBLE_LIMITS.items():
        value = getattr(sample, name)
        if value is None:
            continue
        if not math.isfinite(value):
            problems.append(f"{name} is {value}")
        elif not lo <= value <= hi:
            problems.append(f"{name}={value:g} outside {lo:g}..{hi:g}")
    if sample.status is not None:
        problems.extend(
            f"status flag {flag.name} set" for flag in _FAULT_FLAGS if sample.status & flag
        )
    return tuple(problems)
