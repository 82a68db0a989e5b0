"""Recorder node on a real graph: readable by two readers, bounded loss on kill -9, disk errors."""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from probe import Probe, start_node

from thruster_fdd.core.traces.recording import read_recovered
from thruster_fdd.lifetime import stop_children

pytestmark = pytest.mark.ros

RATE_HZ = 200.0


@dataclass
class Graph:
    """A publisher of numbered telemetry and a /diagnostics listener in this process."""

    probe: Probe
    pub: object
    diagnostics: list

    def publish_for(self, seconds: float, start_seq: int = 0) -> int:
        """Publish at RATE_HZ for ``seconds``; returns the next sequence number."""
        from thruster_fdd_msgs.msg import EscTelemetry

        seq = start_seq
        end = time.monotonic() + seconds
        next_t = time.monotonic()
        while time.monotonic() < end:
            self.pub.publish(EscTelemetry(thruster_id="r0", sequence=seq, rpm=float(seq)))  # type: ignore[attr-defined]
            seq += 1
            next_t += 1.0 / RATE_HZ
            self.probe.executor.spin_once(timeout_sec=max(0.0, next_t - time.monotonic()))
        return seq


@pytest.fixture
def graph() -> Iterator[Graph]:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from thruster_fdd_msgs.msg import EscTelemetry

    with Probe("recorder_probe") as probe:
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        diagnostics: list = []
        probe.node.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda m: diagnostics.extend(s for s in m.status if s.name == "thruster_fdd: recorder"),
            reliable,
        )
        pub = probe.node.create_publisher(EscTelemetry, "/thruster/r0/esc/telemetry", reliable)
        yield Graph(probe, pub, diagnostics)


def _start_recorder(out: Path, **params: object) -> subprocess.Popen[bytes]:
    defaults = {"output_dir": out, "prefix": "test", "discovery_period_s": 0.2}
    return start_node("recorder", params={**defaults, **params})


def _wait_subscribed(graph: Graph, timeout_s: float = 15.0) -> None:
    subscribed = graph.probe.spin_until(
        lambda: graph.pub.get_subscription_count() > 0,  # type: ignore[attr-defined]
        timeout_s,
        0.05,
    )
    assert subscribed, "the recorder never subscribed"


def test_clean_stop_gives_files_two_readers_agree_on(graph: Graph, tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    recorder = _start_recorder(tmp_path)
    try:
        _wait_subscribed(graph)
        sent = graph.publish_for(2.0)
    finally:
        assert not stop_children({"recorder": recorder}, timeout_s=15.0), "no clean stop"
        assert recorder.returncode == 0
    files = sorted(tmp_path.glob("test_*.mcap"))
    assert files
    with files[0].open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None, "a cleanly stopped file has a summary"
        seqs = [
            msg.sequence
            for _, ch, _, msg in reader.iter_decoded_messages(topics=["/thruster/r0/esc/telemetry"])
        ]
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert len(seqs) >= 0.95 * sent, f"recorded {len(seqs)} of {sent}"
    assert seqs == sorted(seqs)
    assert metadata["thruster_fdd"]["vehicle"] == "sim-auv"
    with AnyReader(files) as bag:
        conns = [c for c in bag.connections if c.topic == "/thruster/r0/esc/telemetry"]
        rows = [bag.deserialize(raw, c.msgtype) for c, _, raw in bag.messages(connections=conns)]
    assert [int(r.rpm) for r in rows] == seqs


def test_kill_9_loses_at_most_the_last_flush_period(graph: Graph, tmp_path: Path) -> None:
    recorder = _start_recorder(tmp_path, flush_period_s=0.5, compression="lz4")
    try:
        _wait_subscribed(graph)
        sent = graph.publish_for(3.0)
        recorder.send_signal(signal.SIGKILL)
        recorder.wait(timeout=10)
    finally:
        if recorder.poll() is None:
            recorder.kill()
    recovered = read_recovered(tmp_path / "test_000.mcap")
    assert not recovered.complete, "a killed recorder cannot have written the file's end"
    from rclpy.serialization import deserialize_message
    from thruster_fdd_msgs.msg import EscTelemetry

    seqs = [
        deserialize_message(data, EscTelemetry).sequence
        for topic, _, data, _ in recovered.messages
        if topic == "/thruster/r0/esc/telemetry"
    ]
    assert seqs, "nothing readable after kill -9"
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "holes in what was recovered"
    lost = sent - len(seqs)
    print(f"kill -9: {len(seqs)} of {sent} readable, {lost} lost ({recovered.error})")
    # The flush period plus discovery and shutdown jitter, at RATE_HZ.
    assert lost <= RATE_HZ * (0.5 + 0.5), f"lost {lost} messages"


def test_full_disk_is_reported_and_the_node_survives(graph: Graph, tmp_path: Path) -> None:
    (tmp_path / "test_000.mcap").symlink_to("/dev/full")
    recorder = _start_recorder(tmp_path)
    try:
        _wait_subscribed(graph)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not any(
            s.level == b"\x02" for s in graph.diagnostics
        ):
            graph.publish_for(0.2)
        errors = [s.message for s in graph.diagnostics if s.level == b"\x02"]
        assert errors, "no ERROR on /diagnostics for a full disk"
        assert "No space left" in errors[0]
        assert recorder.poll() is None, "the recorder must keep running"
    finally:
        stop_children({"recorder": recorder}, timeout_s=15.0)


def test_unwritable_folder_is_reported(graph: Graph, tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    recorder = _start_recorder(blocker / "rec")
    try:
        published = graph.probe.spin_until(lambda: bool(graph.diagnostics), 15.0, 0.1)
        assert published, "the recorder published no status"
        status = graph.diagnostics[-1]
        assert status.level == b"\x02"
        assert "cannot record to" in status.message
        assert recorder.poll() is None
    finally:
        stop_children({"recorder": recorder}, timeout_s=15.0)
