"""The bag writer thread: whole bags on close, and disk failures reported, counted and retried
without ever blocking the caller."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import yaml

from thruster_fdd.core.traces.bag_writer import BagWriter, create_bag
from thruster_fdd.core.traces.recording import McapRecorder, RecordingPolicy, read_recovered

TOPIC = "/thruster/w0/esc/telemetry"
TYPE = "thruster_fdd_msgs/msg/EscTelemetry"
QOS = [{"history": "keep_last", "depth": 10, "reliability": "best_effort"}]


def _writer(out: Path, retry_s: float = 0.2, **kwargs: object) -> BagWriter:
    policy = RecordingPolicy(flush_period_s=0.1, compression="none")
    writer = BagWriter(out, "bag", policy, {"vehicle": "test"}, retry_s=retry_s, **kwargs)
    writer.add_topic(TOPIC, TYPE, QOS, "RIHS01_00")
    return writer


def _wait(predicate, timeout_s: float = 10.0) -> bool:  # type: ignore[no-untyped-def]
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and not predicate():
        time.sleep(0.02)
    return predicate()


def _payloads(path: Path) -> list[bytes]:
    return [data for topic, _, data, _ in read_recovered(path).messages if topic == TOPIC]


def test_close_writes_every_message_in_order_into_a_whole_bag(tmp_path: Path) -> None:
    writer = _writer(tmp_path)
    sent = [i.to_bytes(4, "little") for i in range(2000)]
    for data in sent:
        writer.write(TOPIC, TYPE, data, time.time_ns())
    writer.close({"note": "end"})
    status = writer.status()
    assert (status.written, status.dropped, status.queued, status.error) == (2000, 0, 0, "")
    recovered = read_recovered(tmp_path / "bag" / "bag_0.mcap")
    assert recovered.complete
    assert _payloads(tmp_path / "bag" / "bag_0.mcap") == sent
    info = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())
    (topic,) = info["rosbag2_bagfile_information"]["topics_with_message_count"]
    assert topic["message_count"] == 2000
    assert topic["topic_metadata"]["offered_qos_profiles"] == QOS


def test_an_unwritable_folder_is_reported_and_retried_until_it_works(tmp_path: Path) -> None:
    blocker = tmp_path / "out"
    blocker.write_text("a file where the folder should be")
    writer = _writer(blocker)
    start = time.monotonic()
    for i in range(100):
        writer.write(TOPIC, TYPE, bytes([i]), time.time_ns())
    assert time.monotonic() - start < 1.0, "write() waited for the disk"
    assert _wait(lambda: writer.status().error.startswith("cannot record to"))
    assert _wait(lambda: writer.status().dropped == 100)
    writer.status(report=True)
    blocker.unlink()
    blocker.mkdir()
    assert _wait(lambda: writer.status().bag_dir != "")
    writer.write(TOPIC, TYPE, b"after", time.time_ns())
    assert _wait(lambda: writer.status().written == 1)
    assert writer.status().error == "", "a reported error clears once writing works"
    writer.close()
    assert _payloads(blocker / "bag" / "bag_0.mcap") == [b"after"]


def test_a_full_disk_drops_the_file_and_the_next_file_takes_over(tmp_path: Path) -> None:
    writer = _writer(tmp_path)
    assert _wait(lambda: writer.status().bag_dir != "")
    full = tmp_path / "bag" / "bag_0.mcap"
    full.symlink_to("/dev/full")
    # Enough to pass a chunk: the full device refuses it.
    for i in range(3000):
        writer.write(TOPIC, TYPE, i.to_bytes(4, "little") * 64, time.time_ns())
    assert _wait(lambda: "No space left" in writer.status().error)
    assert writer.status(report=True).dropped > 0
    full.unlink()
    time.sleep(0.3)  # past retry_s
    writer.write(TOPIC, TYPE, b"next", time.time_ns())
    writer.close()
    assert writer.status().error == ""
    assert _payloads(tmp_path / "bag" / "bag_1.mcap") == [b"next"]


def test_a_full_queue_drops_instead_of_waiting(tmp_path: Path) -> None:
    writer = _writer(tmp_path, max_queued=10)
    for i in range(10_000):
        writer.write(TOPIC, TYPE, bytes([i % 256]), time.time_ns())
    writer.close()
    status = writer.status()
    assert status.dropped > 0
    assert status.written + status.dropped == 10_000


def test_a_taken_prefix_gets_the_next_free_name(tmp_path: Path) -> None:
    policy = RecordingPolicy()
    first = create_bag(tmp_path, "bag", policy, {})
    second = create_bag(tmp_path, "bag", policy, {})
    assert (first.bag_dir.name, second.bag_dir.name) == ("bag", "bag_2")


@pytest.mark.parametrize("topics", [0, 1, 40])
def test_the_metadata_text_is_the_bag_metadata(tmp_path: Path, topics: int) -> None:
    rec = McapRecorder(tmp_path / "bag", RecordingPolicy(), {"vehicle": "v: with colon"})
    for i in range(topics):
        rec.add_topic(f"/t{i}", TYPE, [*QOS] * (i % 3), f"RIHS01_{i}")
        rec.write(f"/t{i}", TYPE, b"\0\1\0\0", 1_000 + i)
    if topics:
        rec.update_topic("/t0", QOS * 2, "RIHS01_new")
    assert yaml.safe_load(rec.metadata_text()) == rec.bag_metadata()
    rec.close()
