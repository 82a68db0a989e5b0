"""nominal_model node on a real graph: residuals of simulated telemetry, bad input, bad models."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from probe import Probe, start_node

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.lifetime import stop_children
from thruster_fdd_shore.core.sim.scenario import run_scenario

pytestmark = pytest.mark.ros

NOMINAL = default_models_dir() / "nominal"
NS = "/thruster/nm"


@dataclass
class Rig:
    probe: Probe
    pub: object
    residuals: list

    def spin(self, seconds: float) -> None:
        self.probe.spin(seconds)

    def send(self, t: float, command: float, voltage: float, rpm: float, current: float) -> None:
        from thruster_fdd_msgs.msg import EscTelemetry

        msg = EscTelemetry(
            thruster_id="nm", command=command, voltage_v=voltage, rpm=rpm, current_a=current
        )
        msg.header.stamp.sec, frac = divmod(t, 1.0)
        msg.header.stamp.sec = int(msg.header.stamp.sec)
        msg.header.stamp.nanosec = round(frac * 1e9)
        self.pub.publish(msg)  # type: ignore[attr-defined]


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from thruster_fdd_msgs.msg import EscTelemetry, Residual

    assert (NOMINAL / "model_card.json").is_file(), "the committed nominal model is missing"
    # Reliable telemetry (the replay mode, depth 1000) and a reliable residual subscription: the
    # tests count samples, which best-effort queues of depth 5 lose on a loaded machine (374 of
    # 400 seen once); the driver's sensor-data path is tested with the driver and in `up`.
    proc = start_node(
        "nominal_model",
        NS,
        {"thruster_id": "nm", "model_dir": NOMINAL, "reliable_telemetry": "true"},
    )
    with Probe("nominal_probe") as probe:
        residuals: list = []
        probe.node.create_subscription(
            Residual,
            f"{NS}/fdd/residual",
            residuals.append,
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
        )
        pub = probe.node.create_publisher(
            EscTelemetry,
            f"{NS}/esc/telemetry",
            QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE),
        )
        try:
            subscribed = probe.spin_until(lambda: pub.get_subscription_count() > 0, 20.0, 0.1)
            assert subscribed, "the node never subscribed"
            yield Rig(probe, pub, residuals)
        finally:
            stop_children({"nominal_model": proc}, timeout_s=10.0)


def test_residuals_of_a_healthy_thruster_are_small(rig: Rig) -> None:
    trace = run_scenario("t100", "nominal_15v", signal="multilevel", duration_s=40, seed=11)
    n0 = len(rig.residuals)
    for i in range(len(trace)):
        rig.send(1000.0 + trace.t[i], trace.command[i], trace.voltage[i], trace.rpm[i],
                 trace.current[i])  # fmt: skip
        rig.spin(0.004)
    rig.probe.spin_until(lambda: len(rig.residuals) - n0 >= len(trace), 10.0)
    got = rig.residuals[n0:]
    assert len(got) >= 0.95 * len(trace)
    valid = [m for m in got if m.flags == 0]
    assert len(valid) >= 0.9 * len(trace)
    rms_rpm = math.sqrt(sum(m.residual_rpm**2 for m in valid) / len(valid))
    assert rms_rpm < 250.0, f"healthy residual RMS {rms_rpm:.0f} rpm"
    assert all(m.model_id.startswith("nominal-") for m in got)
    assert got[0].flags & 1, "the first samples warm the lookback up"


def test_nan_and_gaps_are_flagged_and_never_published_as_nan(rig: Rig) -> None:
    n0 = len(rig.residuals)
    t = 2000.0
    for _ in range(30):
        rig.send(t, 0.3, 15.0, 1500.0, 1.5)
        t += 0.1
        rig.spin(0.005)
    rig.send(t, 0.3, 15.0, float("nan"), 1.5)
    t += 0.1
    for _ in range(5):
        rig.send(t, 0.3, 15.0, 1500.0, 1.5)
        t += 0.1
        rig.spin(0.005)
    t += 5.0
    rig.send(t, 0.3, 15.0, 1500.0, 1.5)
    rig.probe.spin_until(lambda: len(rig.residuals) - n0 >= 37, 10.0)  # every sample answered
    got = rig.residuals[n0:]
    flags = [m.flags for m in got]
    assert 4 in flags, "INPUT_INVALID for the NaN sample"
    assert any(f & 2 for f in flags), "STATE_RESET after the 5 s gap"
    for m in got:
        for value in (m.measured_rpm, m.predicted_rpm, m.residual_rpm, m.residual_current_a):
            assert math.isfinite(value)


def test_status_carries_the_rms_of_the_periods_ok_residuals(rig: Rig) -> None:
    """A burst of samples within one status period: the status' RMS keys are those of the burst's
    OK residuals (what the live table reads instead of the 50 Hz topic)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    statuses: list = []
    sub = rig.probe.node.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda msg: statuses.extend(
            s for s in msg.status if s.name == "thruster_fdd: nominal_model nm"
        ),
        QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE),
    )

    def values(status: object) -> dict[str, str]:
        return {kv.key: kv.value for kv in status.values}  # type: ignore[attr-defined]

    def next_status() -> dict[str, str]:
        n = len(statuses)
        assert rig.probe.spin_until(lambda: len(statuses) > n, 5.0), "no status"
        return values(statuses[-1])

    try:
        # An idle period's status: no residual, so no RMS (the first may still count some of
        # the previous test's samples).
        next_status()
        idle = next_status()
        assert (idle["rms_residual_rpm"], idle["rms_residual_a"]) == ("-", "-")
        for attempt in range(3):
            before = int(next_status()["residuals_published"])  # a period has just begun
            n0 = len(rig.residuals)
            t0 = 6000.0 + 100.0 * attempt  # a gap: the state resets, warms up, then OK
            for i in range(30):
                rig.send(t0 + 0.1 * i, 0.3, 15.0, 1500.0 + 40.0 * (i % 3), 1.5 + 0.1 * (i % 2))
                rig.spin(0.002)
            assert rig.probe.spin_until(lambda n0=n0: len(rig.residuals) - n0 >= 30, 5.0)
            after = next_status()
            if int(after["residuals_published"]) - before == 30:
                break  # the whole burst in this period
        else:
            pytest.fail("no burst fitted in one status period")
        ok = [m for m in rig.residuals[n0:] if m.flags == 0]
        assert ok, "the burst should outlast the warm-up"
        rms_rpm = math.sqrt(sum(m.residual_rpm**2 for m in ok) / len(ok))
        rms_a = math.sqrt(sum(m.residual_current_a**2 for m in ok) / len(ok))
        assert float(after["rms_residual_rpm"]) == pytest.approx(rms_rpm, abs=0.051)
        assert float(after["rms_residual_a"]) == pytest.approx(rms_a, abs=0.00051)
    finally:
        rig.probe.node.destroy_subscription(sub)


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        ("missing", "model_card.json"),
        ("corrupt", "model.pt2"),
        ("kind", "kind"),
    ],
)
def test_a_bad_model_stops_the_node_with_the_reason(
    tmp_path: Path, damage: str, words: str
) -> None:
    bad = tmp_path / "nominal"
    shutil.copytree(NOMINAL, bad)
    if damage == "missing":
        (bad / "model_card.json").unlink()
    elif damage == "corrupt":
        (bad / "model.pt2").write_bytes(b"not a torch export")
    else:
        card = json.loads((bad / "model_card.json").read_text())
        card["kind"] = "classifier"
        (bad / "model_card.json").write_text(json.dumps(card))
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "thruster_fdd.nodes.nominal_model",
            "--ros-args",
            "-p",
            f"model_dir:={bad}",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1
    assert "cannot start" in out.stderr
    assert words in out.stderr


def _send_some(rig: Rig, t0: float, n: int = 40) -> None:
    for i in range(n):
        rig.send(t0 + 0.1 * i, 0.3, 15.0, 1500.0, 1.5)
        rig.spin(0.005)
    rig.spin(0.5)


def test_a_new_model_is_picked_up_and_a_bad_one_refused(rig: Rig, tmp_path: Path) -> None:
    from thruster_fdd_shore.core.nominal.training import TrainConfig, train_nominal

    traces = [run_scenario("t100", "nominal_15v", signal="multilevel", duration_s=60, seed=5)]
    card = train_nominal(
        traces, tmp_path / "new", seed=1, config=TrainConfig(epochs=2, finetune_epochs=1)
    )
    reload_cmd = ["thruster-fdd", "reload", "--thrusters", "nm", "--timeout", "20"]
    ok = subprocess.run(
        [*reload_cmd, "--nominal", str(tmp_path / "new")], capture_output=True, text=True
    )
    assert ok.returncode == 0, ok.stderr
    n0 = len(rig.residuals)
    _send_some(rig, 3000.0)
    assert {m.model_id for m in rig.residuals[n0:]} == {card.model_id}

    shutil.copytree(tmp_path / "new", tmp_path / "bad")
    (tmp_path / "bad" / "model.pt2").write_bytes(b"truncated")
    refused = subprocess.run(
        [*reload_cmd, "--nominal", str(tmp_path / "bad")], capture_output=True, text=True
    )
    assert refused.returncode == 2, "checked before any node is touched (bad input)"
    assert "model.pt2" in refused.stderr
    n1 = len(rig.residuals)
    _send_some(rig, 4000.0)
    assert {m.model_id for m in rig.residuals[n1:]} == {card.model_id}, "the old model keeps going"
