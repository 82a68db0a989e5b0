"""Traces: CSV and MCAP write -> read -> compare, labels, folders, rosbag2-style definitions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thruster_fdd.core.traces.data import Trace
from thruster_fdd.core.traces.mcap_io import message_definition, read_trace_mcap, write_trace_mcap
from thruster_fdd_shore.core.sim.scenario import run_scenario
from thruster_fdd_shore.core.traces.csv_io import read_command_csv, read_trace_csv, write_trace_csv
from thruster_fdd_shore.core.traces.files import read_traces, write_trace


def _trace(n: int = 50, **kw: object) -> Trace:
    t = np.arange(n) * 0.1
    base = {
        "t": t,
        "command": np.sin(t),
        "voltage": 15.0 + 0.01 * np.cos(t),
        "rpm": 3000 * np.sin(t),
        "current": 2.0 + np.sin(t) ** 2,
        "thruster_id": "t3",
    }
    base.update(kw)
    return Trace(**base)  # type: ignore[arg-type]


def test_trace_validates_columns() -> None:
    with pytest.raises(ValueError, match="strictly increasing"):
        _trace(t=np.array([0.0, 0.2, 0.1] + [0.3] * 47))
    with pytest.raises(ValueError, match="unknown condition"):
        _trace(condition="rusty")
    with pytest.raises(ValueError, match="has 3 samples"):
        _trace(rpm=np.zeros(3))


def test_csv_round_trip(tmp_path: Path) -> None:
    trace = _trace(condition="biofouling", extra={"temperature": np.full(50, 21.5)})
    write_trace_csv(trace, tmp_path / "a.csv")
    back = read_trace_csv(tmp_path / "a.csv")
    assert back.condition == "biofouling"
    assert back.thruster_id == "t3"
    np.testing.assert_allclose(back.rpm, trace.rpm, rtol=1e-5)
    np.testing.assert_allclose(back.t, trace.t, atol=1e-6)
    np.testing.assert_allclose(back.extra["temperature"], 21.5)


def test_csv_with_fault_mid_run_keeps_per_sample_labels(tmp_path: Path) -> None:
    labels = np.array(["nominal_15v"] * 20 + ["broken_blade_2"] * 30, dtype=object)
    write_trace_csv(_trace(labels=labels), tmp_path / "f.csv")
    back = read_trace_csv(tmp_path / "f.csv")
    assert back.condition is None
    assert list(back.sample_labels()) == list(labels)


def test_csv_reader_reports_what_is_wrong(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("t,command,voltage,rpm\n0,0,15,0\n")
    with pytest.raises(ValueError, match="missing trace column"):
        read_trace_csv(bad)
    bad.write_text("t,command,voltage,rpm,current\n0,0,15,zero,0\n")
    with pytest.raises(ValueError, match="'rpm'"):
        read_trace_csv(bad)


def test_mcap_round_trip_with_labels(tmp_path: Path) -> None:
    labels = np.array(["nominal_13v"] * 10 + ["biofouling"] * 40, dtype=object)
    a = _trace(labels=labels)
    b = _trace(thruster_id="t4", condition="nominal_11v8")
    write_trace_mcap([a, b], tmp_path / "x.mcap")
    back = {t.thruster_id: t for t in read_trace_mcap(tmp_path / "x.mcap")}
    assert set(back) == {"t3", "t4"}
    np.testing.assert_allclose(back["t3"].rpm, a.rpm)
    np.testing.assert_allclose(back["t3"].t, a.t, atol=1e-9)
    assert list(back["t3"].sample_labels()) == list(labels)
    assert back["t4"].condition == "nominal_11v8"


def test_mcap_opens_in_independent_readers(tmp_path: Path) -> None:
    """The official mcap-ros2 decoder and rosbags (its own CDR and msg parser) read our files."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    write_trace_mcap([_trace(condition="nominal_15v")], tmp_path / "y.mcap")
    with (tmp_path / "y.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        msgs = list(reader.iter_decoded_messages())
    assert len(msgs) == 50
    schema, channel, _, decoded = msgs[7]
    assert decoded.rpm == pytest.approx(3000 * np.sin(0.7))
    assert channel.topic == "/thruster/t3/esc/telemetry"
    assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr")

    with AnyReader([tmp_path / "y.mcap"]) as reader:
        rows = [
            reader.deserialize(raw, conn.msgtype)
            for conn, _, raw in reader.messages(connections=reader.connections)
        ]
    assert len(rows) == 50
    assert rows[7].rpm == pytest.approx(3000 * np.sin(0.7))
    assert rows[7].header.frame_id == "t3"


def test_message_definition_is_rosbag2_style() -> None:
    text = message_definition("thruster_fdd_msgs/msg/EscTelemetry")
    assert "float64 voltage_v" in text
    sections = text.split("=" * 80 + "\n")
    assert [s.splitlines()[0] for s in sections[1:]] == [
        "MSG: std_msgs/Header",
        "MSG: builtin_interfaces/Time",
    ]
    with pytest.raises(ValueError, match="no definition"):
        message_definition("thruster_fdd_msgs/msg/Nope")


def test_read_traces_from_folders(tmp_path: Path) -> None:
    write_trace(_trace(condition="nominal_15v"), tmp_path / "d" / "a.csv")
    write_trace(_trace(condition="biofouling"), tmp_path / "d" / "sub" / "b.mcap")
    traces = read_traces([tmp_path / "d"])
    assert sorted(t.condition for t in traces) == ["biofouling", "nominal_15v"]
    with pytest.raises(ValueError, match="no such file"):
        read_traces([tmp_path / "missing"])
    with pytest.raises(ValueError, match=r"\.csv or \.mcap"):
        write_trace(_trace(), tmp_path / "a.txt")


def test_command_csv_checks(tmp_path: Path) -> None:
    path = tmp_path / "cmd.csv"
    path.write_text("t,command\n0,0\n1,0.5\n2,-0.25\n")
    _, command = read_command_csv(path)
    np.testing.assert_array_equal(command, [0, 0.5, -0.25])
    path.write_text("t,command\n0,0\n1,1.5\n")
    with pytest.raises(ValueError, match=r"within -1\.\.1"):
        read_command_csv(path)
    path.write_text("t,command\n1,0\n1,0.5\n")
    with pytest.raises(ValueError, match="increasing"):
        read_command_csv(path)


def test_scenario_fault_mid_run_changes_behaviour_and_labels() -> None:
    kw = {"signal": "sine:0.02", "duration_s": 120.0, "rate_hz": 10.0, "seed": 2}
    healthy = run_scenario("t100", "nominal_15v", **kw)
    faulty = run_scenario(
        "t100", "nominal_15v", fault_at_s=60.0, fault_condition="biofouling", **kw
    )
    labels = faulty.sample_labels()
    assert labels[599] == "nominal_15v"
    assert labels[600] == "biofouling"
    # Same unit, same noise: identical before the fault, different after.
    np.testing.assert_array_equal(healthy.rpm[:600], faulty.rpm[:600])
    assert np.abs(healthy.rpm[700:] - faulty.rpm[700:]).mean() > 50.0
    with pytest.raises(ValueError, match="both"):
        run_scenario("t100", "nominal_15v", fault_at_s=3.0)


def test_scenario_follows_a_command_csv(tmp_path: Path) -> None:
    path = tmp_path / "cmd.csv"
    path.write_text(
        "t,command\n" + "".join(f"{i * 0.2},{0.6 if i > 5 else 0}\n" for i in range(60))
    )
    trace = run_scenario("t100", "nominal_13v", command_csv=path)
    assert len(trace) == 60
    assert trace.command[-1] == pytest.approx(0.6)
    assert trace.rpm[-1] > 1000


def test_simulated_recordings_carry_wall_clock_stamps(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    labels = np.array(["nominal_15v"] * 20 + ["broken_blade_1"] * 30, dtype=object)
    write_trace_mcap([_trace(labels=labels)], tmp_path / "w.mcap")
    with (tmp_path / "w.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        stamps = [m.header.stamp.sec for _, _, _, m in reader.iter_decoded_messages()]
        log_times = [m.log_time for _, _, m in reader.iter_messages()]
    assert min(stamps) > 1_700_000_000, "not 1970"
    assert min(log_times) > 1_700_000_000 * 10**9
    (back,) = read_trace_mcap(tmp_path / "w.mcap")
    assert back.t[0] == pytest.approx(0.0, abs=1e-9), "the origin is taken off again"
    assert list(back.sample_labels()) == list(labels)


def test_a_bag_folder_is_one_trace_per_thruster_across_its_files(tmp_path: Path) -> None:
    from thruster_fdd.core.traces.recording import McapRecorder, RecordingPolicy
    from thruster_fdd_shore.core.traces.files import bag_files, trace_files

    # A bag of two split files holding one thruster's telemetry: copy a simulated trace's
    # messages into it as a recorder would receive them.
    write_trace_mcap([_trace(condition="biofouling")], tmp_path / "src.mcap")
    from mcap.reader import make_reader

    rec = McapRecorder(tmp_path / "bag", RecordingPolicy(max_file_duration_s=2.0))
    with (tmp_path / "src.mcap").open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            rec.write(channel.topic, schema.name, message.data, message.log_time)
    rec.close()
    assert len(bag_files(tmp_path / "bag")) >= 2
    assert trace_files([tmp_path]) == [*bag_files(tmp_path / "bag"), tmp_path / "src.mcap"]
    (trace,) = read_traces([tmp_path / "bag"])
    (original,) = read_trace_mcap(tmp_path / "src.mcap")
    assert trace.thruster_id == "t3"
    np.testing.assert_allclose(trace.rpm, original.rpm)
    assert len(read_traces([tmp_path])) == 2, "the loose file and the bag"
    with pytest.raises(ValueError, match="not a bag"):
        bag_files(tmp_path)
