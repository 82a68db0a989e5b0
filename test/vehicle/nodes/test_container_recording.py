"""The recorder hosted in the container: it writes what the process's nodes publish without a
DDS subscription of its own, an external subscriber still gets every message, kill -9 loses at
most a flush period, and an unwritable folder is an ERROR while the models run on."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from probe import Probe

from thruster_fdd.core.traces.recording import read_recovered
from thruster_fdd.lifetime import stop_children

pytestmark = pytest.mark.ros

NS = "/thruster/cr"
FLUSH_S = 0.5
SAMPLE_S = 0.1  # the nominal model's sample time: one residual per telemetry message


def _container(out: Path) -> subprocess.Popen[bytes]:
    cmd = [sys.executable, "-m", "thruster_fdd.nodes.container", "nominal_model"]
    cmd += ["--thrusters", "cr", "--vehicle", "recorder"]
    cmd += ["-p", "nominal_model:reliable_telemetry=true"]
    cmd += ["-p", f"recorder:output_dir={out}", "-p", "recorder:prefix=bag"]
    cmd += ["-p", f"recorder:flush_period_s={FLUSH_S}", "-p", "recorder:include=^/thruster/"]
    return subprocess.Popen(cmd)


class _Feed:
    """Telemetry into the container's nominal model, its residuals and the recorder's status
    out, on a probe (the external subscriber)."""

    def __init__(self, probe: Probe) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from thruster_fdd_msgs.msg import EscTelemetry, Residual

        from thruster_fdd.nodes.nominal_model import RESIDUAL_QOS

        self.probe = probe
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.residuals: list[tuple[int, int]] = []  # (sequence, receive time ns)
        self.statuses: list = []
        node = probe.node
        node.create_subscription(
            Residual,
            f"{NS}/fdd/residual",
            lambda m: self.residuals.append((m.header.stamp.sec, time.time_ns())),
            RESIDUAL_QOS,
        )
        node.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda m: self.statuses.extend(
                s for s in m.status if s.name == "thruster_fdd: recorder"
            ),
            reliable,
        )
        self.pub = node.create_publisher(EscTelemetry, f"{NS}/esc/telemetry", reliable)
        self.seq = 0

    def wait_ready(self) -> None:
        ready = self.probe.spin_until(
            lambda: self.pub.get_subscription_count() > 0 and bool(self.statuses), 60.0, 0.05
        )
        assert ready, "the container never subscribed or reported"

    def publish_for(self, seconds: float, rate_hz: float = 20.0) -> None:
        from thruster_fdd_msgs.msg import EscTelemetry

        end = time.monotonic() + seconds
        while time.monotonic() < end:
            # The stamp's seconds carry the sequence; stamps 0.1 s apart (the model's rate).
            msg = EscTelemetry(thruster_id="cr", command=0.2, voltage_v=15.0, rpm=900.0)
            msg.sequence = self.seq
            msg.header.stamp.sec = 1000 + self.seq
            msg.header.stamp.nanosec = 0
            self.seq += 1
            self.pub.publish(msg)
            self.probe.spin(1.0 / rate_hz)


def _recorded_stamps(path: Path) -> list[tuple[int, int]]:
    from rclpy.serialization import deserialize_message
    from thruster_fdd_msgs.msg import Residual

    return [
        (deserialize_message(data, Residual).header.stamp.sec, log_ns)
        for topic, _, data, log_ns in read_recovered(path).messages
        if topic == f"{NS}/fdd/residual"
    ]


def test_kill_9_loses_at_most_one_flush_and_nothing_subscribes_twice(tmp_path: Path) -> None:
    proc = _container(tmp_path)
    try:
        with Probe("container_recording_probe") as probe:
            feed = _Feed(probe)
            feed.wait_ready()
            feed.publish_for(4.0)
            subscribers = probe.node.get_subscriptions_info_by_topic(f"{NS}/fdd/residual")
            killed_ns = time.time_ns()
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert [s.node_name for s in subscribers] == ["container_recording_probe"], (
        "the recorder must take the residuals by a direct call, not over DDS"
    )
    assert len(feed.residuals) >= 40, "the external subscriber got too few residuals"
    recorded = _recorded_stamps(tmp_path / "bag" / "bag_0.mcap")
    assert recorded, "nothing readable after kill -9"
    seqs = [s for s, _ in recorded]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "holes in what was recovered"
    assert seqs[0] == feed.residuals[0][0], "the bag misses the first residuals"
    # Lost: what the external subscriber got after the last recorded message's write.
    lost_s = (killed_ns - recorded[-1][1]) * 1e-9
    print(f"kill -9: {len(recorded)} of {len(feed.residuals)} residuals readable, {lost_s:.2f} s")
    # One flush period, and scheduling slack on a loaded machine.
    assert lost_s <= FLUSH_S + 0.25, f"lost the last {lost_s:.2f} s"


def test_an_unwritable_folder_is_an_error_and_the_model_runs_on(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    proc = _container(blocker / "rec")
    try:
        with Probe("container_recording_probe") as probe:
            feed = _Feed(probe)
            feed.wait_ready()
            feed.publish_for(2.0)
            probe.spin_until(lambda: any(s.level == b"\x02" for s in feed.statuses), 15.0, 0.1)
            alive = proc.poll() is None
    finally:
        assert not stop_children({"container": proc}, timeout_s=20.0), "no clean stop"
    errors = [s.message for s in feed.statuses if s.level == b"\x02"]
    assert errors, "no ERROR on /diagnostics for an unwritable folder"
    assert "cannot record to" in errors[0]
    assert alive
    assert len(feed.residuals) >= 15, "the model must keep publishing"
    assert proc.returncode == 0
