"""McapRecorder without ROS: splitting, schemas, abandon after errors, recovery of a cut file."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader

from thruster_fdd.core.traces.recording import McapRecorder, RecordingPolicy, read_recovered

DEF = "float64 rpm\n"


def _recorder(tmp_path: Path, **policy: object) -> McapRecorder:
    return McapRecorder(
        tmp_path,
        RecordingPolicy(**policy),  # type: ignore[arg-type]
        {"vehicle": "v"},
        prefix="r",
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
    assert [p.name for p in rec.files] == ["r_000.mcap", "r_001.mcap", "r_002.mcap"]
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
    assert [p.name for p in rec.files] == ["r_000.mcap", "r_001.mcap"]
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
