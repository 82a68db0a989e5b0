"""McapRecorder without ROS: bag folders rosbags reads (metadata, QoS, split files), splitting,
schemas, types nobody can describe, abandon after errors, recovery of a cut file."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader

from thruster_fdd.core.traces.recording import McapRecorder, RecordingPolicy, read_recovered

DEF = "float64 rpm\n"


def _recorder(tmp_path: Path, **policy: object) -> McapRecorder:
    return McapRecorder(
        tmp_path / "r",
        RecordingPolicy(**policy),  # type: ignore[arg-type]
        {"vehicle": "v"},
        definition_for=lambda _: DEF,
    )


def test_policy_rejects_bad_values() -> None:
    with pytest.raises(ValueError, match="compression"):
        RecordingPolicy(compression="gzip")
    with pytest.raises(ValueError, match="chunk_bytes"):
        RecordingPolicy(chunk_bytes=0)


def test_split_by_duration_and_every_file_complete(tmp_path: Path) -> None:
    rec = _recorder(tmp_path, max_file_duration_s=1.0)
    for i in range(30):
        rec.write("/a", "p/msg/T", bytes(8), i * 100_000_000)  # 10 Hz for 3 s
    rec.close()
    assert [p.name for p in rec.files] == ["r_0.mcap", "r_1.mcap", "r_2.mcap"]
    counts = []
    for path in rec.files:
        with path.open("rb") as f:
            reader = make_reader(f)
            schema = next(iter(reader.get_summary().schemas.values()))
            assert (schema.encoding, schema.data) == ("ros2msg", DEF.encode())
            counts.append(sum(1 for _ in reader.iter_messages()))
    assert sum(counts) == 30
    assert max(counts) <= 11


def test_split_by_size(tmp_path: Path) -> None:
    rec = _recorder(tmp_path, max_file_bytes=20_000, chunk_bytes=4096, compression="none")
    for i in range(200):
        rec.write("/a", "p/msg/T", bytes(500), i)
    rec.close()
    assert len(rec.files) >= 4
    assert rec.messages_written == 200


def test_abandon_moves_to_a_new_file_and_keeps_the_old_one(tmp_path: Path) -> None:
    rec = _recorder(tmp_path, flush_period_s=1e-6)
    for i in range(5):
        rec.write("/a", "p/msg/T", bytes(8), i)
    rec.abandon()
    rec.write("/a", "p/msg/T", bytes(8), 10)
    rec.close()
    assert [p.name for p in rec.files] == ["r_0.mcap", "r_1.mcap"]
    first = read_recovered(rec.files[0])
    assert not first.complete
    assert len(first.messages) == 5
    assert read_recovered(rec.files[1]).complete


def test_recovery_of_a_file_cut_anywhere(tmp_path: Path) -> None:
    rec = _recorder(tmp_path, flush_period_s=1e-6, chunk_bytes=256)
    for i in range(100):
        rec.write("/a", "p/msg/T", i.to_bytes(8, "little"), i)
    rec.close()
    data = rec.files[0].read_bytes()
    previous = -1
    for cut in range(0, len(data), max(1, len(data) // 40)):
        (tmp_path / "cut.mcap").write_bytes(data[:cut])
        got = read_recovered(tmp_path / "cut.mcap")
        values = [int.from_bytes(m[2], "little") for m in got.messages]
        assert values == list(range(len(values))), "recovered messages must be a clean prefix"
        assert len(values) >= previous
        previous = len(values)
    assert previous >= 95


TELEMETRY = "thruster_fdd_msgs/msg/EscTelemetry"
LATCHED = {
    "history": "unknown",
    "depth": 0,
    "reliability": "reliable",
    "durability": "transient_local",
    "deadline": {"sec": 9223372036, "nsec": 854775807},
    "lifespan": {"sec": 9223372036, "nsec": 854775807},
    "liveliness": "automatic",
    "liveliness_lease_duration": {"sec": 9223372036, "nsec": 854775807},
    "avoid_ros_namespace_conventions": False,
}


def _telemetry(seq: int) -> bytes:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from thruster_fdd.core.traces.mcap_io import message_definition

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(message_definition(TELEMETRY), TELEMETRY))
    cls = store.types[TELEMETRY]
    header = store.types["std_msgs/msg/Header"]
    stamp = store.types["builtin_interfaces/msg/Time"](sec=1_800_000_000 + seq, nanosec=0)
    msg = cls(header(stamp, "t0"), "t0", seq, 0.1, 1540, 15.0, 1.0, float(seq), 20.0, 0)
    return bytes(store.serialize_cdr(msg, TELEMETRY))


def test_a_bag_folder_rosbags_reads_with_qos_and_counts(tmp_path: Path) -> None:
    from rosbags.interfaces import QosDurability, QosReliability
    from rosbags.rosbag2 import Reader

    rec = McapRecorder(tmp_path / "run", RecordingPolicy(max_file_duration_s=1.0), {"vehicle": "v"})
    rec.add_topic("/thruster/t0/fdd/residual_like", TELEMETRY, [LATCHED], "RIHS01_" + "ab" * 32)
    for i in range(25):  # 2.5 s at 10 Hz: three files
        rec.write("/thruster/t0/fdd/residual_like", TELEMETRY, _telemetry(i), (10 + i) * 10**8)
    rec.write("/nobody/knows", "nope_msgs/msg/Nothing", b"\x00\x01\x00\x00", 35 * 10**8)
    rec.close({"messages": "26"})
    assert len(rec.files) == 3
    with Reader(tmp_path / "run") as bag:
        assert bag.message_count == 26
        assert bag.ros_distro == "jazzy"
        assert bag.start_time == 10**9
        (conn,) = [c for c in bag.connections if c.topic.endswith("residual_like")]
        assert conn.msgcount == 25
        assert conn.digest == "RIHS01_" + "ab" * 32
        (qos,) = conn.ext.offered_qos_profiles
        assert qos.durability == QosDurability.TRANSIENT_LOCAL
        assert qos.reliability == QosReliability.RELIABLE
        assert bag.storage.metadata.custom["vehicle"] == "v"
        rows = [raw for c, _, raw in bag.messages(connections=[conn])]
        (unknown,) = [c for c in bag.connections if c.topic == "/nobody/knows"]
        assert sum(1 for _ in bag.messages(connections=[unknown])) == 1
    assert len(rows) == 25
    # Each channel's offered QoS also sits in the MCAP files (the ros2 profile requires it).
    with rec.files[0].open("rb") as f:
        channels = make_reader(f).get_summary().channels.values()
        meta = {c.topic: c.metadata for c in channels}
    assert "transient_local" in meta["/thruster/t0/fdd/residual_like"]["offered_qos_profiles"]


def test_a_bag_is_never_overwritten(tmp_path: Path) -> None:
    rec = _recorder(tmp_path)
    rec.write("/a", "p/msg/T", bytes(8), 1)
    rec.close()
    with pytest.raises(FileExistsError):
        _recorder(tmp_path)


def test_a_folder_the_recorder_did_not_create_is_not_written_into(tmp_path: Path) -> None:
    """Another recorder's folder before its first message (no metadata.yaml yet) is refused."""
    first = _recorder(tmp_path)
    assert list(first.bag_dir.iterdir()) == []
    with pytest.raises(FileExistsError):
        _recorder(tmp_path)
    first.write("/a", "p/msg/T", bytes(8), 1)
    first.close()
    assert sorted(p.name for p in first.bag_dir.iterdir()) == ["metadata.yaml", "r_0.mcap"]


def test_metadata_follows_a_recording_that_is_killed(tmp_path: Path) -> None:
    import yaml

    rec = _recorder(tmp_path, flush_period_s=1e-6)
    for i in range(40):
        rec.write("/a", "p/msg/T", bytes(8), i * 10**7)
    # No close: what a kill -9 leaves. metadata.yaml was rewritten at every flush.
    info = yaml.safe_load((tmp_path / "r" / "metadata.yaml").read_text())
    bag = info["rosbag2_bagfile_information"]
    assert bag["message_count"] >= 39
    assert bag["relative_file_paths"] == ["r_0.mcap"]
    assert read_recovered(rec.files[0]).messages
