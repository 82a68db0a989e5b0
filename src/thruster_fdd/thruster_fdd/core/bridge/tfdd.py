"""The tfdd v1 bridge protocol between the ESC driver and the thruster microcontroller.

Framed, versioned, sequence-numbered, CRC-16: telemetry goes bridge -> host, commands host ->
bridge. Layouts, units and error rules in docs/protocol.md; this module holds the messages,
their encoders, the streaming decoder and the sequence-number rule. No ROS import.
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass
from typing import Literal

from thruster_fdd.core.bridge.crc import crc16_ccitt_false
from thruster_fdd.core.bridge.stuck import StuckRun

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
    stuck_low_bytes, stuck_high_bytes : int
        Bytes in runs of at least ``stuck.STUCK_RUN_BYTES`` 0x00 (line stuck low) or 0xFF
        (stuck high) bytes: a link fault, never telemetry.
    """

    bytes_received: int = 0
    frames_ok: int = 0
    crc_errors: int = 0
    garbage_bytes: int = 0
    resyncs: int = 0
    truncated: int = 0
    unknown_type: int = 0
    bad_version: int = 0
    stuck_low_bytes: int = 0
    stuck_high_bytes: int = 0


def checked_int(name: str, value: int, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} must be an int, got {type(value).__name__}")
    if not lo <= value <= hi:
        raise ValueError(f"{name}={value} outside {lo}..{hi}")
    return value


def scaled_int(name: str, value: float, scale: float, lo: int, hi: int) -> int:
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
    checked_int("seq", seq, 0, SEQ_MODULUS - 1)
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
        checked_int("timestamp_us", frame.timestamp_us, 0, 0xFFFF_FFFF),
        checked_int("pwm_us", frame.pwm_us, 0, 0xFFFF),
        scaled_int("voltage_v", frame.voltage_v, 100, 0, 0xFFFF),
        scaled_int("current_a", frame.current_a, 100, -0x8000, 0x7FFF),
        scaled_int("rpm", frame.rpm, 1, -0x8000_0000, 0x7FFF_FFFF),
        scaled_int("temperature_c", frame.temperature_c, 100, -0x8000, 0x7FFF),
        checked_int("status", frame.status, 0, 0xFF),
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
        checked_int("pwm_us", frame.pwm_us, PWM_COMMAND_MIN_US, PWM_COMMAND_MAX_US),
        checked_int("timeout_ms", frame.timeout_ms, 1, 0xFFFF),
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
        checked_int("major", frame.major, 0, 0xFF),
        checked_int("minor", frame.minor, 0, 0xFF),
        checked_int("patch", frame.patch, 0, 0xFF),
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
        self._stuck = StuckRun()

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
        self._stuck.feed(data)
        self._counts["stuck_low_bytes"] = self._stuck.low_bytes
        self._counts["stuck_high_bytes"] = self._stuck.high_bytes
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
    checked_int("prev", prev, 0, SEQ_MODULUS - 1)
    checked_int("new", new, 0, SEQ_MODULUS - 1)
    delta = (new - prev) % SEQ_MODULUS
    if delta == 0:
        return SeqCheck("duplicate")
    if delta == 1:
        return SeqCheck("ok")
    if delta < SEQ_MODULUS // 2:
        return SeqCheck("lost", delta - 1)
    return SeqCheck("reordered")


NEUTRAL_PWM_US = 1500
"""Pulse of a stopped thruster, us (command 0)."""

PWM_PER_UNIT = 400.0
"""Microseconds of pulse per unit of normalised command: ``command = (pwm_us - 1500) / 400``."""
