"""Tests of the serial bridge protocols (tfdd v1 and KISS / BLHeli_32 telemetry)."""

from __future__ import annotations

import dataclasses
import math
import re
import struct
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from thruster_fdd.core.bridge.crc import crc8_kiss, crc16_ccitt_false
from thruster_fdd.core.bridge.kiss import KISS_FRAME_LEN, KissDecoder, KissFrame, encode_kiss
from thruster_fdd.core.bridge.plausibility import TelemetrySample, check_telemetry, to_sample
from thruster_fdd.core.bridge.tfdd import (
    HEADER_LEN,
    MAX_FRAME_LEN,
    MAX_PAYLOAD_LEN,
    SYNC,
    CommandFrame,
    DecodedFrame,
    DecoderStats,
    FrameDecoder,
    MsgType,
    SeqCheck,
    StatusFlag,
    TelemetryFrame,
    VersionFrame,
    VersionQuery,
    classify_seq,
    encode_command,
    encode_telemetry,
    encode_version,
    encode_version_query,
)

DOC = Path(__file__).resolve().parents[3] / "docs" / "protocol.md"

settings.register_profile(
    "protocol", deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=150
)
FAST = settings(settings.get_profile("protocol"))

GOOD_TELEMETRY = TelemetryFrame(123456789, 1700, 15.0, 3.25, -2100.0, 24.5, 0)
GOOD_KISS = KissFrame(31.0, 15.0, 3.25, 120, 2100.0)


# ----------------------------------------------------------------------------- references


def _crc16_bitwise(data: bytes) -> int:
    """Textbook bit-at-a-time CRC-16/CCITT-FALSE, independent of the module's implementation."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def _crc8_betaflight(data: bytes) -> int:
    """Line-by-line port of Betaflight / KISS ``update_crc8`` + ``get_crc8``."""

    def update_crc8(crc: int, crc_seed: int) -> int:
        crc_u = (crc ^ crc_seed) & 0xFF
        for _ in range(8):
            crc_u = (0x7 ^ (crc_u << 1)) & 0xFF if crc_u & 0x80 else (crc_u << 1) & 0xFF
        return crc_u

    crc = 0
    for byte in data:
        crc = update_crc8(byte, crc)
    return crc


def _tfdd_valid_starts(data: bytes) -> set[int]:
    """Offsets where a CRC-valid tfdd frame starts (brute force, independent of FrameDecoder)."""
    starts = set()
    for i in range(len(data) - 8):
        if data[i : i + 2] != SYNC or data[i + 6] > MAX_PAYLOAD_LEN:
            continue
        end = i + 9 + data[i + 6]
        if end <= len(data) and _crc16_bitwise(data[i + 2 : end - 2]) == int.from_bytes(
            data[end - 2 : end], "little"
        ):
            starts.add(i)
    return starts


def _kiss_valid_starts(data: bytes) -> set[int]:
    return {
        i
        for i in range(len(data) - KISS_FRAME_LEN + 1)
        if _crc8_betaflight(data[i : i + 9]) == data[i + 9]
    }


def _encode(frame: DecodedFrame) -> bytes:
    msg = frame.message
    if isinstance(msg, TelemetryFrame):
        return encode_telemetry(msg, frame.seq)
    if isinstance(msg, CommandFrame):
        return encode_command(msg, frame.seq)
    if isinstance(msg, VersionFrame):
        return encode_version(msg, frame.seq)
    return encode_version_query(frame.seq)


def _with_crc(body: bytes) -> bytes:
    return SYNC + body + _crc16_bitwise(body).to_bytes(2, "little")


# ----------------------------------------------------------------------------- strategies

seqs = st.integers(0, 0xFFFF)
telemetry_frames = st.builds(
    TelemetryFrame,
    timestamp_us=st.integers(0, 0xFFFF_FFFF),
    pwm_us=st.integers(0, 0xFFFF),
    voltage_v=st.floats(0.0, 655.0),
    current_a=st.floats(-327.0, 327.0),
    rpm=st.floats(-2.0e9, 2.0e9),
    temperature_c=st.floats(-327.0, 327.0),
    status=st.integers(0, 0xFF),
)
command_frames = st.builds(
    CommandFrame, pwm_us=st.integers(1000, 2000), timeout_ms=st.integers(1, 0xFFFF)
)
version_frames = st.builds(VersionFrame, *(st.integers(0, 255) for _ in range(3)))
encoded_frames = st.one_of(
    st.builds(encode_telemetry, telemetry_frames, seqs),
    st.builds(encode_command, command_frames, seqs),
    st.builds(encode_version, version_frames, seqs),
    st.builds(encode_version_query, seqs),
)
# A powered ESC reports a voltage: ten 0x00 bytes (0 V) are a stuck line, never a frame.
kiss_frames = st.builds(
    KissFrame,
    temperature_c=st.floats(0.0, 255.0),
    voltage_v=st.floats(0.01, 655.0),
    current_a=st.floats(0.0, 655.0),
    consumption_mah=st.integers(0, 0xFFFF),
    rpm=st.floats(0.0, 93_000.0),  # the eRPM/100 field's limit with 7 pole pairs
)
pole_pairs = st.integers(1, 255)
# Noise that looks like the start of frames: random bytes, bare syncs and cut-off frames.
tfdd_noise = st.lists(
    st.one_of(
        st.binary(max_size=40),
        st.just(SYNC),
        st.tuples(encoded_frames, st.integers(1, 25)).map(
            lambda fk: fk[0][: min(fk[1], len(fk[0]) - 1)]
        ),
    ),
    max_size=4,
).map(b"".join)


# ----------------------------------------------------------------------------- CRCs


def test_crc_check_values() -> None:
    assert crc16_ccitt_false(b"123456789") == 0x29B1
    assert crc8_kiss(b"123456789") == 0xF4
    assert crc16_ccitt_false(b"") == 0xFFFF
    assert crc8_kiss(b"") == 0


@FAST
@given(st.binary(max_size=64))
def test_crcs_match_reference_implementations(data: bytes) -> None:
    assert crc16_ccitt_false(data) == _crc16_bitwise(data)
    assert crc8_kiss(data) == _crc8_betaflight(data)


# ----------------------------------------------------------------------------- round trips


@FAST
@given(telemetry_frames, seqs)
def test_telemetry_round_trip_within_quantisation(frame: TelemetryFrame, seq: int) -> None:
    data = encode_telemetry(frame, seq)
    assert len(data) == 26
    (decoded,) = FrameDecoder().feed(data)
    assert decoded.seq == seq
    msg = decoded.message
    assert isinstance(msg, TelemetryFrame)
    assert (msg.timestamp_us, msg.pwm_us, msg.status) == (
        frame.timestamp_us,
        frame.pwm_us,
        frame.status,
    )
    for name in ("voltage_v", "current_a", "temperature_c"):
        assert abs(getattr(msg, name) - getattr(frame, name)) <= 0.005 + 1e-9
    assert abs(msg.rpm - frame.rpm) <= 0.5
    assert encode_telemetry(msg, seq) == data


@FAST
@given(command_frames, version_frames, seqs)
def test_command_and_version_round_trip(
    command: CommandFrame, version: VersionFrame, seq: int
) -> None:
    data = encode_command(command, seq) + encode_version(version, seq) + encode_version_query(seq)
    assert FrameDecoder().feed(data) == [
        DecodedFrame(seq, command),
        DecodedFrame(seq, version),
        DecodedFrame(seq, VersionQuery()),
    ]


@FAST
@given(kiss_frames, pole_pairs, st.data())
def test_kiss_round_trip_within_quantisation(
    frame: KissFrame, pp: int, data: st.DataObject
) -> None:
    frame = dataclasses.replace(frame, rpm=data.draw(st.floats(0.0, 65535 * 100 / pp - 100)))
    data = encode_kiss(frame, pp)
    assert len(data) == KISS_FRAME_LEN
    (msg,) = KissDecoder(pp).feed(data)
    assert msg.consumption_mah == frame.consumption_mah
    assert abs(msg.temperature_c - frame.temperature_c) <= 0.5
    assert abs(msg.voltage_v - frame.voltage_v) <= 0.005 + 1e-9
    assert abs(msg.current_a - frame.current_a) <= 0.005 + 1e-9
    assert abs(msg.rpm - frame.rpm) <= 50 / pp + 1e-6
    assert encode_kiss(msg, pp) == data


def test_kiss_rpm_uses_pole_pairs() -> None:
    # eRPM/100 = 147 -> 14 700 eRPM -> 2100 rpm with 7 pole pairs, 2940 rpm with 5.
    data = encode_kiss(GOOD_KISS, 7)
    assert data[7:9] == (147).to_bytes(2, "big")
    assert KissDecoder(5).feed(data)[0].rpm == pytest.approx(2940.0)


# ----------------------------------------------------------------------------- arbitrary input


@FAST
@given(st.lists(st.binary(max_size=200), max_size=8))
def test_decoders_never_raise_and_stay_bounded(chunks: list[bytes]) -> None:
    tfdd, kiss = FrameDecoder(), KissDecoder()
    for chunk in chunks:
        tfdd.feed(chunk)
        kiss.feed(chunk)
        assert tfdd.buffered <= MAX_FRAME_LEN
        assert kiss.buffered < KISS_FRAME_LEN
    total = sum(map(len, chunks))
    assert tfdd.stats().bytes_received == total
    assert kiss.stats().bytes_received == total


def test_buffer_bounded_under_long_noise() -> None:
    noise = bytes(range(256)) * 400 + SYNC + b"\x01\x01\x00\x00"
    tfdd, kiss = FrameDecoder(), KissDecoder()
    tfdd.feed(noise)
    kiss.feed(noise)
    assert tfdd.buffered <= MAX_FRAME_LEN
    assert kiss.buffered < KISS_FRAME_LEN
    # Nothing is lost after the noise: frames decode normally.
    assert tfdd.feed(bytes(40) + encode_telemetry(GOOD_TELEMETRY, 1))[-1].message == GOOD_TELEMETRY
    assert tfdd.stats().garbage_bytes >= len(noise) - MAX_FRAME_LEN


# ----------------------------------------------------------------------------- chunking


@pytest.mark.parametrize(
    "frame",
    [
        encode_telemetry(GOOD_TELEMETRY, 65535),
        encode_command(CommandFrame(1500, 100), 0),
        encode_version(VersionFrame(1, 0, 0), 3),
        encode_version_query(4),
    ],
)
def test_tfdd_frame_survives_every_split(frame: bytes) -> None:
    for cut in range(len(frame) + 1):
        decoder = FrameDecoder()
        out = decoder.feed(frame[:cut]) + decoder.feed(frame[cut:])
        assert [_encode(f) for f in out] == [frame], cut
        assert decoder.buffered == 0


def test_kiss_frame_survives_every_split() -> None:
    frame = encode_kiss(GOOD_KISS)
    for cut in range(len(frame) + 1):
        decoder = KissDecoder()
        assert decoder.feed(frame[:cut]) + decoder.feed(frame[cut:]) == [GOOD_KISS], cut


@FAST
@given(st.lists(encoded_frames, min_size=1, max_size=5), st.data())
def test_tfdd_stream_survives_any_chunking(frames: list[bytes], data: st.DataObject) -> None:
    stream = b"".join(frames)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    decoder = FrameDecoder()
    out = []
    for lo, hi in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        out += decoder.feed(stream[lo:hi])
    assert [_encode(f) for f in out] == frames
    assert decoder.stats().frames_ok == len(frames)


@FAST
@given(st.lists(kiss_frames, min_size=1, max_size=5), st.data())
def test_kiss_stream_survives_any_chunking(frames: list[KissFrame], data: st.DataObject) -> None:
    encoded = [encode_kiss(f) for f in frames]
    stream = b"".join(encoded)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    decoder = KissDecoder()
    out = []
    for lo, hi in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        out += decoder.feed(stream[lo:hi])
    assert [encode_kiss(f) for f in out] == encoded


# ----------------------------------------------------------------------------- noise


@FAST
@given(st.lists(st.tuples(tfdd_noise, encoded_frames), min_size=1, max_size=4), tfdd_noise)
def test_tfdd_frames_recovered_from_noise(pieces: list[tuple[bytes, bytes]], tail: bytes) -> None:
    stream, starts, spans = b"", [], []
    for noise, frame in pieces:
        stream += noise
        starts.append(len(stream))
        spans.append(range(len(stream), len(stream) + len(frame)))
        stream += frame
    stream += tail
    # The noise must not itself hold a valid frame (nested in a real frame does not matter).
    stray = _tfdd_valid_starts(stream) - set(starts)
    assume(all(any(i in span for span in spans) for i in stray))
    out = FrameDecoder().feed(stream)
    assert [_encode(f) for f in out] == [frame for _, frame in pieces]


@FAST
@given(
    st.lists(st.tuples(st.binary(max_size=30), kiss_frames), min_size=1, max_size=4),
    st.binary(max_size=30),
)
def test_kiss_frames_recovered_from_noise(
    pieces: list[tuple[bytes, KissFrame]], tail: bytes
) -> None:
    stream, starts = b"", set()
    for noise, frame in pieces:
        stream += noise
        starts.add(len(stream))
        stream += encode_kiss(frame)
    stream += tail
    # An 8-bit CRC passes 1 in 256 random windows; only streams without such windows qualify.
    assume(_kiss_valid_starts(stream) == starts)
    decoder = KissDecoder()
    out = decoder.feed(stream)
    assert [encode_kiss(f) for f in out] == [encode_kiss(f) for _, f in pieces]
    assert decoder.stats().garbage_bytes == len(stream) - 10 * len(pieces) - decoder.buffered


# ----------------------------------------------------------------------------- corruption


@pytest.mark.parametrize(
    "frame",
    [
        encode_telemetry(GOOD_TELEMETRY, 258),
        encode_command(CommandFrame(1650, 250), 7),
        encode_version(VersionFrame(1, 2, 3), 9),
        encode_version_query(8),
    ],
)
def test_every_single_bit_flip_is_rejected(frame: bytes) -> None:
    good = encode_telemetry(GOOD_TELEMETRY, 1)
    for bit in range(len(frame) * 8):
        corrupted = bytearray(frame)
        corrupted[bit // 8] ^= 1 << (bit % 8)
        decoder = FrameDecoder()
        out = decoder.feed(good + bytes(corrupted) + good)
        assert [_encode(f) for f in out] == [good, good], bit
        stats = decoder.stats()
        if bit >= 16:  # past the sync bytes a candidate frame forms and must fail
            assert stats.crc_errors + stats.truncated + stats.bad_version >= 1, bit
        else:
            assert stats.garbage_bytes >= 1, bit


@FAST
@given(encoded_frames, st.data())
def test_random_bit_flips_never_return_a_frame(frame: bytes, data: st.DataObject) -> None:
    bit = data.draw(st.integers(0, len(frame) * 8 - 1))
    corrupted = bytearray(frame)
    corrupted[bit // 8] ^= 1 << (bit % 8)
    good = encode_command(CommandFrame(1500, 200), 5)
    # Two good frames: a corrupted length byte may claim up to MAX_FRAME_LEN bytes.
    out = FrameDecoder().feed(bytes(corrupted) + good + good)
    assert [_encode(f) for f in out] == [good, good]


def test_payload_bit_flip_counts_as_crc_error() -> None:
    frame = bytearray(encode_telemetry(GOOD_TELEMETRY, 258))
    frame[10] ^= 0x04
    decoder = FrameDecoder()
    assert decoder.feed(bytes(frame)) == []
    stats = decoder.stats()
    assert (stats.crc_errors, stats.truncated, stats.resyncs, stats.frames_ok) == (1, 0, 1, 0)


def test_kiss_every_single_bit_flip_is_rejected() -> None:
    good = encode_kiss(GOOD_KISS)
    for bit in range(KISS_FRAME_LEN * 8):
        corrupted = bytearray(good)
        corrupted[bit // 8] ^= 1 << (bit % 8)
        decoder = KissDecoder()
        assert decoder.feed(good + bytes(corrupted)) == [GOOD_KISS], bit
        stats = decoder.stats()
        assert (stats.crc_errors, stats.resyncs, stats.frames_ok) == (1, 1, 1), bit


@FAST
@given(kiss_frames, st.integers(0, KISS_FRAME_LEN * 8 - 1))
def test_kiss_random_bit_flip_never_returns_a_frame(frame: KissFrame, bit: int) -> None:
    corrupted = bytearray(encode_kiss(frame))
    corrupted[bit // 8] ^= 1 << (bit % 8)
    assert KissDecoder().feed(bytes(corrupted)) == []


@FAST
@given(encoded_frames, st.integers(1, 40), encoded_frames)
def test_truncated_frame_then_good_frame(cut_from: bytes, keep: int, good: bytes) -> None:
    truncated = cut_from[: min(keep, len(cut_from) - 1)]
    # The good frame's first byte may complete a cut just before the CRC's last byte.
    assume(_tfdd_valid_starts(truncated + good) == {len(truncated)})
    decoder = FrameDecoder()
    out = decoder.feed(truncated + good)
    assert [_encode(f) for f in out] == [good]
    stats = decoder.stats()
    if len(truncated) >= 2:
        assert stats.truncated + stats.crc_errors + stats.bad_version >= 1


def test_truncated_by_new_sync_is_counted_as_truncated() -> None:
    good = encode_telemetry(GOOD_TELEMETRY, 2)
    decoder = FrameDecoder()
    assert decoder.feed(good[:12] + good) == [DecodedFrame(2, GOOD_TELEMETRY)]
    stats = decoder.stats()
    assert (stats.truncated, stats.crc_errors, stats.frames_ok) == (1, 0, 1)


@FAST
@given(kiss_frames, st.integers(1, 9), kiss_frames)
def test_kiss_truncated_frame_then_good_frame(cut: KissFrame, keep: int, good: KissFrame) -> None:
    stream = encode_kiss(cut)[:keep] + encode_kiss(good)
    assume(_kiss_valid_starts(stream) == {keep})
    (out,) = KissDecoder().feed(stream)
    assert encode_kiss(out) == encode_kiss(good)


def test_impossible_length_is_truncated_and_skipped() -> None:
    bogus = SYNC + bytes([1, MsgType.TELEMETRY, 0, 0, MAX_PAYLOAD_LEN + 1])
    good = encode_command(CommandFrame(1600, 100), 3)
    decoder = FrameDecoder()
    assert decoder.feed(bogus + good) == [DecodedFrame(3, CommandFrame(1600, 100))]
    stats = decoder.stats()
    assert (stats.truncated, stats.resyncs, stats.garbage_bytes) == (1, 1, len(bogus))


def test_unknown_type_with_valid_crc_is_skipped_whole() -> None:
    good = encode_version_query(9)
    decoder = FrameDecoder()
    unknown = _with_crc(bytes([1, 0x7F, 0, 0, 2]) + SYNC)
    assert decoder.feed(unknown + good) == [DecodedFrame(9, VersionQuery())]
    stats = decoder.stats()
    assert (stats.unknown_type, stats.frames_ok, stats.crc_errors, stats.garbage_bytes) == (
        1,
        1,
        0,
        0,
    )


@pytest.mark.parametrize(
    ("body", "counter"),
    [
        (bytes([2, MsgType.COMMAND, 0, 0, 4]) + struct.pack("<HH", 1500, 100), "bad_version"),
        (bytes([1, MsgType.COMMAND, 0, 0, 3]) + b"\x00\x01\x02", "truncated"),
    ],
)
def test_impossible_header_is_rejected_before_waiting(body: bytes, counter: str) -> None:
    good = encode_version_query(9)
    decoder = FrameDecoder()
    # Only the header arrives: it is rejected at once, not after waiting for its length.
    assert decoder.feed(_with_crc(body)[:HEADER_LEN]) == []
    assert getattr(decoder.stats(), counter) == 1
    assert decoder.feed(_with_crc(body)[HEADER_LEN:] + good) == [DecodedFrame(9, VersionQuery())]
    stats = decoder.stats()
    assert (getattr(stats, counter), stats.frames_ok, stats.crc_errors) == (1, 1, 0)


def test_stats_is_a_frozen_snapshot() -> None:
    decoder = FrameDecoder()
    before = decoder.stats()
    decoder.feed(encode_version_query(0))
    assert before == DecoderStats()
    assert decoder.stats().frames_ok == 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        before.frames_ok = 3  # type: ignore[misc]


# ----------------------------------------------------------------------------- sequence numbers


@pytest.mark.parametrize(
    ("prev", "new", "expected"),
    [
        (65535, 0, SeqCheck("ok")),
        (41, 42, SeqCheck("ok")),
        (7, 7, SeqCheck("duplicate")),
        (65535, 65535, SeqCheck("duplicate")),
        (10, 13, SeqCheck("lost", 2)),
        (65534, 1, SeqCheck("lost", 2)),
        (13, 10, SeqCheck("reordered")),
        (0, 65535, SeqCheck("reordered")),
        (5000, 0, SeqCheck("reordered")),
    ],
)
def test_classify_seq_examples(prev: int, new: int, expected: SeqCheck) -> None:
    assert classify_seq(prev, new) == expected


@FAST
@given(seqs, st.integers(1, 32766))
def test_classify_seq_counts_losses_across_wrap(prev: int, lost: int) -> None:
    assert classify_seq(prev, (prev + 1 + lost) % 65536) == SeqCheck("lost", lost)
    assert classify_seq((prev + 1 + lost) % 65536, prev).status == "reordered"


@pytest.mark.parametrize(("prev", "new"), [(-1, 0), (0, 65536)])
def test_classify_seq_rejects_out_of_range(prev: int, new: int) -> None:
    with pytest.raises(ValueError, match="outside"):
        classify_seq(prev, new)


# ----------------------------------------------------------------------------- encoder validation


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("voltage_v", math.nan),
        ("voltage_v", 655.36),
        ("voltage_v", -0.01),
        ("current_a", math.inf),
        ("current_a", 327.68),
        ("current_a", -327.69),
        ("rpm", -math.inf),
        ("rpm", 2.0**31),
        ("temperature_c", math.nan),
        ("temperature_c", -400.0),
        ("timestamp_us", 2**32),
        ("timestamp_us", -1),
        ("pwm_us", 70000),
        ("pwm_us", 1500.0),
        ("status", 256),
        ("status", True),
    ],
)
def test_encode_telemetry_rejects_bad_values(field: str, value: float) -> None:
    frame = dataclasses.replace(GOOD_TELEMETRY, **{field: value})
    with pytest.raises(ValueError, match=field):
        encode_telemetry(frame, 0)


@pytest.mark.parametrize("seq", [-1, 65536])
def test_encoders_reject_bad_seq(seq: int) -> None:
    with pytest.raises(ValueError, match="seq"):
        encode_telemetry(GOOD_TELEMETRY, seq)
    with pytest.raises(ValueError, match="seq"):
        encode_version_query(seq)


@pytest.mark.parametrize(
    "frame",
    [
        CommandFrame(999, 100),
        CommandFrame(2001, 100),
        CommandFrame(1500, 0),
        CommandFrame(1500, 70000),
    ],
)
def test_encode_command_rejects_bad_values(frame: CommandFrame) -> None:
    with pytest.raises(ValueError, match="outside"):
        encode_command(frame, 0)


def test_encode_version_rejects_bad_values() -> None:
    with pytest.raises(ValueError, match="minor"):
        encode_version(VersionFrame(1, 256, 0), 0)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("temperature_c", -1.0),
        ("temperature_c", 256.0),
        ("voltage_v", math.nan),
        ("current_a", -0.01),
        ("consumption_mah", 65536),
        ("rpm", -100.0),
        ("rpm", math.inf),
        ("rpm", 1.0e6),
    ],
)
def test_encode_kiss_rejects_bad_values(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        encode_kiss(dataclasses.replace(GOOD_KISS, **{field: value}))


@pytest.mark.parametrize("pp", [0, 256])
def test_kiss_rejects_bad_pole_pairs(pp: int) -> None:
    with pytest.raises(ValueError, match="pole_pairs"):
        KissDecoder(pp)
    with pytest.raises(ValueError, match="pole_pairs"):
        encode_kiss(GOOD_KISS, pp)


# ----------------------------------------------------------------------------- plausibility


def test_check_telemetry_accepts_plausible_samples() -> None:
    assert check_telemetry(GOOD_TELEMETRY) == ()
    assert check_telemetry(GOOD_KISS) == ()


def test_check_telemetry_lists_each_problem() -> None:
    bad = dataclasses.replace(
        GOOD_TELEMETRY, voltage_v=75.0, rpm=math.nan, status=StatusFlag.ADC_FAULT
    )
    problems = check_telemetry(bad)
    assert len(problems) == 3
    assert any("voltage_v" in p for p in problems)
    assert any("rpm" in p and "nan" in p for p in problems)
    assert any("ADC_FAULT" in p for p in problems)
    # Flags that describe state, not bad data, are not problems.
    assert check_telemetry(dataclasses.replace(GOOD_TELEMETRY, status=StatusFlag.ESC_TIMEOUT)) == ()


def test_kiss_sample_has_missing_fields_as_none() -> None:
    sample = to_sample(GOOD_KISS)
    assert sample == TelemetrySample(15.0, 3.25, 2100.0, 31.0, consumption_mah=120)
    assert check_telemetry(dataclasses.replace(GOOD_KISS, current_a=80.0)) == (
        "current_a=80 outside -60..60",
    )


# ----------------------------------------------------------------------------- documentation


def _doc_examples() -> dict[str, bytes]:
    text = DOC.read_text(encoding="utf-8")
    found = re.findall(r"<!-- example:(\w+) -->\s*```text\n([0-9a-f ]+)\n```", text)
    return {name: bytes.fromhex(hex_bytes) for name, hex_bytes in found}


def test_doc_examples_match_encoder() -> None:
    examples = _doc_examples()
    assert set(examples) == {"telemetry", "command", "kiss"}
    assert examples["telemetry"] == encode_telemetry(GOOD_TELEMETRY, 258)
    assert examples["command"] == encode_command(CommandFrame(1650, 250), 7)
    assert examples["kiss"] == encode_kiss(GOOD_KISS, 7)
    assert FrameDecoder().feed(examples["telemetry"]) == [DecodedFrame(258, GOOD_TELEMETRY)]
