"""Recorder node on a real graph: a rosbag2 bag two readers agree on, with the publishers' QoS;
bounded loss and a readable bag after kill -9; types nobody can describe; disk errors."""

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
    files = sorted((tmp_path / "test").glob("test_*.mcap"))
    assert [f.name for f in files] == ["test_0.mcap"]
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
    with AnyReader([tmp_path / "test"]) as bag:  # the bag folder, through its metadata.yaml
        conns = [c for c in bag.connections if c.topic == "/thruster/r0/esc/telemetry"]
        rows = [bag.deserialize(raw, c.msgtype) for c, _, raw in bag.messages(connections=conns)]
        (qos,) = conns[0].ext.offered_qos_profiles
        assert qos.reliability.name == "RELIABLE", "the publisher's offer"
        assert conns[0].digest.startswith("RIHS01_")
        assert conns[0].msgcount == len(seqs)
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
    recovered = read_recovered(tmp_path / "test" / "test_0.mcap")
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
    # metadata.yaml, rewritten at every flush, describes what the cut file holds (a recorder
    # killed itself cannot write the file's end; killed `up` lets it finish: test_up.py).
    import yaml

    info = yaml.safe_load((tmp_path / "test" / "metadata.yaml").read_text())
    bag = info["rosbag2_bagfile_information"]
    assert bag["relative_file_paths"] == ["test_0.mcap"]
    (topic,) = [
        t
        for t in bag["topics_with_message_count"]
        if t["topic_metadata"]["name"] == "/thruster/r0/esc/telemetry"
    ]
    assert abs(topic["message_count"] - len(seqs)) <= RATE_HZ * 0.5


def test_full_disk_is_reported_and_the_node_survives(graph: Graph, tmp_path: Path) -> None:
    # Only the telemetry, which comes when this test publishes it.
    recorder = _start_recorder(tmp_path, include="^/thruster/")
    try:
        _wait_subscribed(graph)
        # The recorder made its bag folder at start and opens its first file at the first
        # message: that file is the full device.
        (tmp_path / "test" / "test_0.mcap").symlink_to("/dev/full")
        # Bounded generously: in a full suite the recorder once took longer than 10 s to say it.
        deadline = time.monotonic() + 30
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


def test_two_recorders_with_one_prefix_write_two_whole_bags(graph: Graph, tmp_path: Path) -> None:
    """Started together with the same output folder and prefix, each recorder writes a bag
    folder of its own (the second one ``<prefix>_2``), and both bags read whole."""
    from rosbags.highlevel import AnyReader

    recorders = {"a": _start_recorder(tmp_path), "b": _start_recorder(tmp_path)}
    try:
        subscribed = graph.probe.spin_until(
            lambda: graph.pub.get_subscription_count() >= 2,  # type: ignore[attr-defined]
            20.0,
            0.05,
        )
        assert subscribed, "the recorders never both subscribed"
        sent = graph.publish_for(1.5)
    finally:
        assert not stop_children(recorders, timeout_s=15.0), "no clean stop"
    assert [p.returncode for p in recorders.values()] == [0, 0]
    bags = sorted(p.name for p in tmp_path.iterdir())
    assert bags == ["test", "test_2"]
    for name in bags:
        assert sorted(p.name for p in (tmp_path / name).iterdir()) == [
            "metadata.yaml",
            f"{name}_0.mcap",
        ]
        with AnyReader([tmp_path / name]) as bag:
            conns = [c for c in bag.connections if c.topic == "/thruster/r0/esc/telemetry"]
            seqs = [
                bag.deserialize(raw, c.msgtype).sequence
                for c, _, raw in bag.messages(connections=conns)
            ]
        assert len(seqs) >= 0.9 * sent, f"{name}: recorded {len(seqs)} of {sent}"
        assert seqs == sorted(set(seqs)), f"{name}: messages repeated or out of order"


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


def test_types_nobody_installed_are_recorded_and_the_recorder_lives(
    graph: Graph, tmp_path: Path
) -> None:
    """Without the workspace in AMENT_PREFIX_PATH no .msg file is found: standard types come
    from rosbags' type store, ours get an empty definition; nothing stops the recorder."""
    import os
    import sys

    from rosbags.rosbag2 import Reader

    from thruster_fdd.lifetime import node_command

    cmd = node_command(
        "recorder",
        params={"output_dir": tmp_path, "prefix": "bare", "discovery_period_s": 0.2},
    )
    assert cmd[0] == sys.executable
    recorder = subprocess.Popen(cmd, env={**os.environ, "AMENT_PREFIX_PATH": ""})
    try:
        _wait_subscribed(graph)
        sent = graph.publish_for(1.0)
        graph.probe.spin(1.5)  # a /diagnostics status or two to record
        assert recorder.poll() is None, "the recorder died"
    finally:
        assert not stop_children({"recorder": recorder}, timeout_s=15.0)
    with Reader(tmp_path / "bare") as bag:
        by_topic = {c.topic: c for c in bag.connections}
        ours = by_topic["/thruster/r0/esc/telemetry"]
        assert ours.msgcount >= 0.9 * sent
        assert ours.msgdef.data == ""
        assert "DiagnosticStatus" in by_topic["/diagnostics"].msgdef.data, "from rosbags"


def test_publishers_that_appear_after_the_recorder_subscribed_give_their_qos(
    tmp_path: Path,
) -> None:
    """Under ``up`` the drivers' publishers come after the nominal models' subscriptions: the
    recorder subscribes a topic it sees through a subscriber only, and must take the QoS and
    type hash of the publisher that appears later (metadata.yaml and the MCAP channel)."""
    import yaml
    from mcap.reader import make_reader
    from rclpy.qos import qos_profile_sensor_data
    from rosbags.rosbag2 import Reader
    from thruster_fdd_msgs.msg import EscTelemetry

    topic = "/thruster/late/esc/telemetry"
    with Probe("recorder_late_probe") as probe:
        probe.node.create_subscription(
            EscTelemetry, topic, lambda _m: None, qos_profile_sensor_data
        )
        recorder = _start_recorder(tmp_path)
        try:
            subscribed = probe.spin_until(
                lambda: any(
                    info.node_name == "recorder"
                    for info in probe.node.get_subscriptions_info_by_topic(topic)
                ),
                15.0,
                0.05,
            )
            assert subscribed, "the recorder never subscribed to the subscriber-only topic"
            pub = probe.node.create_publisher(EscTelemetry, topic, qos_profile_sensor_data)
            probe.spin_until(lambda: pub.get_subscription_count() >= 2, 10.0, 0.05)
            for seq in range(100):
                pub.publish(EscTelemetry(thruster_id="late", sequence=seq))
                probe.spin(0.01)
            probe.spin(1.0)  # a discovery period or more
        finally:
            assert not stop_children({"recorder": recorder}, timeout_s=15.0), "no clean stop"
    info = yaml.safe_load((tmp_path / "test" / "metadata.yaml").read_text())
    (meta,) = [
        t["topic_metadata"]
        for t in info["rosbag2_bagfile_information"]["topics_with_message_count"]
        if t["topic_metadata"]["name"] == topic
    ]
    assert meta["type_description_hash"].startswith("RIHS01_"), meta
    (offered,) = meta["offered_qos_profiles"]
    assert offered["reliability"] == "best_effort", offered
    assert offered["durability"] == "volatile", offered
    with Reader(tmp_path / "test") as bag:
        (conn,) = [c for c in bag.connections if c.topic == topic]
        assert conn.msgcount > 0
        assert conn.digest.startswith("RIHS01_")
    with (tmp_path / "test" / "test_0.mcap").open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    (channel,) = [c for c in summary.channels.values() if c.topic == topic]
    assert "best_effort" in channel.metadata["offered_qos_profiles"], channel.metadata
    assert channel.metadata["topic_type_hash"].startswith("RIHS01_")
