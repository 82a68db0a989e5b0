"""Adversarial files: damaged recordings, files that are not recordings, traces in wrong units.

Every reader takes what a damaged recording still holds, with one warning saying how much was
lost, never returns a sample that differs from what was written, and refuses with
BadInputError what is not a recording or a trace.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import Writer as RawWriter
from mcap_ros2.writer import Writer

from thruster_fdd.core.errors import BadInputError, PartialInputWarning
from thruster_fdd.core.traces.data import Trace, TraceWarning
from thruster_fdd.core.traces.mcap_io import (
    METADATA_NAME,
    TELEMETRY_TYPE,
    message_definition,
    read_trace_mcap,
    telemetry_topic,
)
from thruster_fdd.core.traces.mcap_read import DamagedRecordingWarning, McapContents, read_mcap
from thruster_fdd.core.traces.recording import read_recovered
from thruster_fdd_shore.core.traces.csv_io import read_command_csv, read_trace_csv, write_trace_csv
from thruster_fdd_shore.core.traces.replay_check import load_bag

N = 400
FEW = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _write_recording(path: Path, n: int = N, chunk_size: int = 1500) -> np.ndarray:
    """A recording as the recorder makes it (many small zstd chunks, CRCs on) of one thruster's
    telemetry; returns the rpm written, shape (n,) (rpm = sample index, so any wrong sample
    shows)."""
    rpm = np.arange(n, dtype=float)
    with path.open("wb") as f:
        writer = Writer(f, chunk_size=chunk_size)
        schema = writer.register_msgdef(TELEMETRY_TYPE, message_definition(TELEMETRY_TYPE))
        for i in range(n):
            stamp = 1_000_000_000 + i * 100_000_000
            message = {
                "header": {"stamp": {"sec": stamp // 10**9, "nanosec": stamp % 10**9}},
                "thruster_id": "t0",
                "sequence": i,
                "command": 0.5,
                "pwm_us": 1700,
                "voltage_v": 15.0,
                "current_a": 2.0,
                "rpm": rpm[i],
                "temperature_c": 20.0,
                "status": 0,
            }
            writer.write_message(telemetry_topic("t0"), schema, message, stamp, stamp, i)
        writer._writer.add_metadata(METADATA_NAME, {"labels.t0": "0:nominal_15v"})
        writer.finish()
    return rpm


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("rec") / "r.mcap"
    _write_recording(path)
    return path.read_bytes()


_RECORDING: list[bytes] = []


def _recording_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """The recording for hypothesis tests (not an argument: its repr would be 40 kB)."""
    if not _RECORDING:
        path = tmp_path_factory.mktemp("rec") / "r.mcap"
        _write_recording(path)
        _RECORDING.append(path.read_bytes())
    return _RECORDING[0]


def _read(path: Path) -> tuple[list[Trace] | None, list[str]]:
    """read_trace_mcap's traces (None when refused) and the warnings it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            traces = read_trace_mcap(path)
        except BadInputError:
            traces = None
    return traces, [str(w.message) for w in caught if issubclass(w.category, PartialInputWarning)]


def test_sound_recording_reads_whole_without_warning(tmp_path: Path, recording: bytes) -> None:
    (tmp_path / "r.mcap").write_bytes(recording)
    traces, said = _read(tmp_path / "r.mcap")
    assert said == []
    assert traces is not None
    np.testing.assert_array_equal(traces[0].rpm, np.arange(N))
    assert traces[0].condition == "nominal_15v"
    assert read_mcap(tmp_path / "r.mcap").complete


def test_file_cut_anywhere_gives_a_clean_prefix_and_says_so(
    tmp_path: Path, recording: bytes
) -> None:
    """A recording cut by kill -9 (at every 97th byte): a prefix of the samples and one
    warning, or a refusal when nothing is left; never a traceback."""
    path = tmp_path / "cut.mcap"
    previous = 0
    for cut in range(0, len(recording) - 1, 97):
        path.write_bytes(recording[:cut])
        traces, said = _read(path)
        if traces is None:
            assert previous == 0, f"cut at {cut}: refused after samples were readable"
            continue
        rpm = traces[0].rpm
        np.testing.assert_array_equal(rpm, np.arange(len(rpm)))
        assert len(rpm) >= previous
        previous = len(rpm)
        assert len(said) == 1
        assert "ends early" in said[0]
        assert re.search(rf"\({len(rpm)}( of {N})? messages read\)", said[0]), said[0]
    assert previous > 0.9 * N


def test_chunk_with_its_type_damaged_is_counted_lost(tmp_path: Path, recording: bytes) -> None:
    """The first chunk's type byte hit (0x06 ^ 0x80: a private type, skipped): its messages are
    lost and said, from the message indexes behind it (found by hypothesis, flip (70, 128))."""
    data = bytearray(recording)
    first = _chunk_offsets(recording)[0]
    assert data[first] == 0x06
    data[first] ^= 0x80
    (tmp_path / "f.mcap").write_bytes(bytes(data))
    traces, said = _read(tmp_path / "f.mcap")
    assert traces is not None
    assert sum(len(t) for t in traces) < N
    assert len(said) == 1
    assert "a chunk with its type damaged" in said[0]
    assert "message(s) lost" in said[0]


def test_five_bytes_short_reads_everything_with_a_warning(tmp_path: Path, recording: bytes) -> None:
    path = tmp_path / "short.mcap"
    path.write_bytes(recording[:-5])
    traces, said = _read(path)
    assert traces is not None
    assert len(traces[0]) == N
    assert said
    assert "closing magic" in said[0]


@FEW
@given(
    flips=st.lists(st.tuples(st.integers(0, 10**9), st.integers(1, 255)), min_size=1, max_size=4)
)
def test_flipped_bytes_never_give_a_wrong_sample(
    tmp_path_factory: pytest.TempPathFactory, flips: list[tuple[int, int]]
) -> None:
    """Bytes flipped anywhere: refused, or samples that are each exactly as written (a damaged
    chunk fails its CRC and is skipped, never decoded into other numbers), with a warning."""
    data = bytearray(_recording_bytes(tmp_path_factory))
    for position, mask in flips:
        data[position % len(data)] ^= mask
    path = tmp_path_factory.mktemp("flip") / "f.mcap"
    path.write_bytes(bytes(data))
    traces, said = _read(path)
    if traces is None:
        return
    for trace in traces:
        index = np.rint((trace.t - 1.0) / 0.1).astype(int)
        np.testing.assert_array_equal(trace.rpm, index.astype(float))
        assert np.all(trace.voltage == 15.0)
    if sum(len(t) for t in traces) < N:
        assert said, "samples were lost without a warning"


def test_damaged_chunk_is_skipped_and_counted(tmp_path: Path, recording: bytes) -> None:
    contents = read_mcap_bytes(tmp_path, recording)
    chunk_at = [p for p in _chunk_offsets(recording)][2]
    data = bytearray(recording)
    data[chunk_at + 80] ^= 0x10  # inside the compressed data of the third chunk
    (tmp_path / "d.mcap").write_bytes(bytes(data))
    traces, said = _read(tmp_path / "d.mcap")
    assert traces is not None
    lost = N - len(traces[0])
    assert 0 < lost < N / 4
    assert f"{lost} message(s) lost" in said[0]
    assert f"{len(contents.messages) - lost} of {N} messages read" in said[0]


def read_mcap_bytes(tmp_path: Path, data: bytes) -> McapContents:
    (tmp_path / "whole.mcap").write_bytes(data)
    return read_mcap(tmp_path / "whole.mcap")


def _chunk_offsets(data: bytes) -> list[int]:
    from thruster_fdd.core.traces.mcap_read import MAGIC, _records

    return [
        offset for offset, opcode, _ in _records(data, len(MAGIC), len(data), []) if opcode == 0x06
    ]


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"", "it is empty"),
        (b"t,command,voltage,rpm,current\n0,0,15,0,0\n", "starts with the text 't,command"),
        (bytes(range(200, 256)) * 4, "starts with bytes c8 c9"),
        (b"\x89MCAP0\r\n", "no message could be read"),
        (b"\x89MCAP0\r\n" + b"\x01" + (2**62).to_bytes(8, "little"), "runs past the end"),
    ],
)
def test_what_is_not_a_recording_is_refused_in_one_line(
    tmp_path: Path, content: bytes, words: str
) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(content)
    for reader in (read_trace_mcap, lambda p: load_bag(p, 0.1)):
        with pytest.raises(BadInputError, match=words) as info:
            reader(path)
        assert "\n" not in str(info.value)


def test_read_recovered_refuses_another_format_but_takes_a_cut_magic(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(b"t,command\n")
    with pytest.raises(BadInputError, match="not an MCAP"):
        read_recovered(path)
    path.write_bytes(b"\x89MCA")
    got = read_recovered(path)
    assert (got.messages, got.complete) == ([], False)


def test_telemetry_channel_of_another_encoding_or_schema_is_skipped(tmp_path: Path) -> None:
    path = tmp_path / "mixed.mcap"
    with path.open("wb") as f:
        raw = RawWriter(f)
        raw.start(profile="ros2")
        json_schema = raw.register_schema("x/msg/Json", "jsonschema", b"{}")
        other = raw.register_schema("pkg/msg/Other", "ros2msg", b"float64 x\n")
        bad_text = raw.register_schema(TELEMETRY_TYPE, "ros2msg", b"this is ] not a msg\n")
        for tid, schema, encoding in (
            ("t1", json_schema, "json"),
            ("t2", other, "cdr"),
            ("t3", bad_text, "cdr"),
        ):
            channel = raw.register_channel(telemetry_topic(tid), encoding, schema)
            for i in range(3):
                raw.add_message(channel, i, json.dumps({"rpm": 1}).encode(), i)
        raw.finish()
    with (
        pytest.raises(BadInputError, match="no readable"),
        pytest.warns(DamagedRecordingWarning, match="t1/esc/telemetry: x/msg/Json in jsonschema"),
    ):
        read_trace_mcap(path)
    with (
        pytest.raises(BadInputError, match="no readable"),
        pytest.warns(DamagedRecordingWarning, match="3 message.s. of another type"),
    ):
        load_bag(path, 0.1)


def test_good_and_bad_channels_together_keep_the_good(tmp_path: Path) -> None:
    path = tmp_path / "mixed.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        schema = writer.register_msgdef(TELEMETRY_TYPE, message_definition(TELEMETRY_TYPE))
        for i in range(20):
            message = {"header": {"stamp": {"sec": i}}, "voltage_v": 15.0, "rpm": float(i)}
            writer.write_message(telemetry_topic("t0"), schema, message, i, i, i)
        raw = writer._writer
        cut = raw.register_channel(telemetry_topic("t9"), "cdr", schema.id)
        raw.add_message(cut, 1, b"\x00\x01\x00\x00\x01", 1)  # a CDR message cut short
        json_schema = raw.register_schema("x/msg/Json", "jsonschema", b"{}")
        other = raw.register_channel(telemetry_topic("t1"), "json", json_schema)
        raw.add_message(other, 1, b"{}", 1)
        writer.finish()
    with pytest.warns(DamagedRecordingWarning) as caught:
        traces = read_trace_mcap(path)
    assert [t.thruster_id for t in traces] == ["t0"]
    np.testing.assert_array_equal(traces[0].rpm, np.arange(20.0))
    text = str(caught[0].message)
    assert "1 telemetry message(s) do not decode" in text
    assert "x/msg/Json in jsonschema / json" in text


def test_load_bag_reads_a_cut_recording_with_a_warning(tmp_path: Path, recording: bytes) -> None:
    path = tmp_path / "cut.mcap"
    path.write_bytes(recording[: len(recording) // 2])
    with pytest.warns(DamagedRecordingWarning, match="ends early"):
        (bag,) = load_bag(path, 0.1)
    assert 0 < len(bag.stamps_ns) < N
    assert bag.truth == ()  # simulated recordings write their labels at the end


def test_malformed_label_metadata_is_bad_input(tmp_path: Path) -> None:
    path = tmp_path / "m.mcap"
    _write_recording(path, n=20)
    data = path.read_bytes().replace(b"0:nominal_15v", b"x:nominal_15v")
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the data section CRC no longer matches
        with pytest.raises(BadInputError, match="label metadata"):
            read_trace_mcap(path)
        with pytest.raises(BadInputError, match="label metadata"):
            load_bag(path, 0.1)


# ----------------------------------------------------------------------------- trace CSV


def _csv(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "trace.csv"
    path.write_text(text)
    return path


def _rows(t: np.ndarray, command: np.ndarray, extra: str = "") -> str:
    lines = [f"t,command,voltage,rpm,current{extra}"]
    lines += [f"{a},{c},15.0,1000,2.0" for a, c in zip(t, command, strict=True)]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("t", "command", "words"),
    [
        (np.arange(50) * 0.1, 1500 + 400 * np.sin(np.arange(50)), "pulse width in µs"),
        (np.arange(50) * 0.1, 60 * np.sin(np.arange(50)), "percent"),
        (np.arange(50) * 100.0, 0.5 * np.sin(np.arange(50)), "looks like ms"),
        (np.arange(50) * 1e5, 0.5 * np.sin(np.arange(50)), "looks like µs"),
    ],
)
def test_wrong_units_are_refused_with_a_hint(
    tmp_path: Path, t: np.ndarray, command: np.ndarray, words: str
) -> None:
    """A command in µs or a time in ms gave 0 windows and exit 0; now exit 2 with a hint."""
    with pytest.raises(BadInputError, match=words):
        read_trace_csv(_csv(tmp_path, _rows(t, command)))


@pytest.mark.parametrize(
    ("column", "scale", "words"),
    [("voltage", 1000.0, "mV"), ("current", 1000.0, "mA"), ("rpm", 14.0, "eRPM")],
)
def test_thousandfold_values_are_refused_with_a_hint(
    tmp_path: Path, column: str, scale: float, words: str
) -> None:
    t = np.arange(40) * 0.1
    values = {"voltage": 15.0, "current": 20.0, "rpm": 3000.0}
    values[column] *= scale
    text = "t,command,voltage,rpm,current\n" + "".join(
        f"{a},0.5,{values['voltage']},{values['rpm']},{values['current']}\n" for a in t
    )
    with pytest.raises(BadInputError, match=words):
        read_trace_csv(_csv(tmp_path, text))


def test_duplicated_column_is_refused(tmp_path: Path) -> None:
    text = "t,command,voltage,rpm,current,rpm\n0,0,15,0,0,5\n0.1,0,15,0,0,5\n"
    with pytest.raises(BadInputError, match="rpm appear more than once"):
        read_trace_csv(_csv(tmp_path, text))
    with pytest.raises(BadInputError, match="more than once"):
        read_command_csv(_csv(tmp_path, "t,command,t\n0,0,0\n1,0,1\n"))


def test_non_finite_rows_are_left_out_and_counted(tmp_path: Path) -> None:
    t = np.arange(30) * 0.1
    text = _rows(t, np.zeros(30)).replace("\n0.5,0.0,15.0,1000,2.0", "\n0.5,nan,15.0,1000,2.0")
    text = text.replace("\n0.7000000000000001,0.0,15.0", "\n0.7000000000000001,0.0,inf")
    with pytest.warns(TraceWarning, match="left out 2 of 30 samples.*command, voltage"):
        trace = read_trace_csv(_csv(tmp_path, text))
    assert len(trace) == 28
    with pytest.raises(BadInputError, match="every sample"):
        read_trace_csv(_csv(tmp_path, "t,command,voltage,rpm,current\nnan,0,15,0,0\n"))


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"\x89MCAP0\r\n\x00\xff\xfe", "not a text CSV"),
        (b"t,command,voltage,rpm,current\n0,0,15,0,0\n0,0,15,0,0\n", "sample 1 is 0 s after 0 s"),
        (b"t,command,voltage,rpm,current\n" + b'0,"' + b"x" * 200_000 + b'",1,1,1\n', "CSV"),
    ],
)
def test_unreadable_csv_is_bad_input(tmp_path: Path, content: bytes, words: str) -> None:
    path = tmp_path / "x.csv"
    path.write_bytes(content)
    with pytest.raises(BadInputError, match=words) as info:
        read_trace_csv(path)
    assert str(path) in str(info.value)


def test_csv_write_is_atomic(tmp_path: Path) -> None:
    path = tmp_path / "out.csv"
    path.write_text("old\n")
    bad = Trace(np.arange(3.0), np.zeros(3), np.ones(3), np.zeros(3), np.zeros(3))
    object.__setattr__(bad, "extra", {"x": np.zeros(2)})  # a column one short: fails mid-write
    with pytest.raises(IndexError):
        write_trace_csv(bad, path)
    assert path.read_text() == "old\n"
    assert list(tmp_path.iterdir()) == [path]
