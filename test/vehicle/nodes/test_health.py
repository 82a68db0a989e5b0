"""health node on a real graph: VehicleHealth from diagnoses and residuals, masks, staleness,
publishing on change, a late subscriber, the /diagnostics status."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import pytest
from probe import Probe, start_node

from thruster_fdd.lifetime import stop_children
from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import simulate
from thruster_fdd_shore.core.sim.plant import severity_spec
from thruster_fdd_shore.core.sim.signals import make_signal

pytestmark = pytest.mark.ros

IDS = ("h0", "h1")


@dataclass
class Rig:
    probe: Probe
    diag_pubs: dict
    res_pubs: dict
    health: list = field(default_factory=list)
    statuses: list = field(default_factory=list)

    def diagnosis(self, tid: str, label: str, confidence: float = 0.9) -> None:
        from thruster_fdd_msgs.msg import Diagnosis

        self.diag_pubs[tid].publish(Diagnosis(thruster_id=tid, label=label, confidence=confidence))

    def residuals(self, tid: str, t0: float, command, voltage, rpm, current) -> None:
        from thruster_fdd_msgs.msg import Residual

        for i in range(len(command)):
            msg = Residual(
                thruster_id=tid,
                command=float(command[i]),
                voltage_v=float(voltage[i]),
                measured_rpm=float(rpm[i]),
                measured_current_a=float(current[i]),
                model_id="nominal-test",
            )
            stamp_ns = round((t0 + 0.1 * i) * 1e9)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
            self.res_pubs[tid].publish(msg)
            if i % 20 == 0:
                self.probe.spin(0.01)


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from thruster_fdd_msgs.msg import Diagnosis, Residual, VehicleHealth

    proc = start_node(
        "health",
        "/",
        {"thruster_ids": f"[{','.join(IDS)}]", "period_s": 5.0, "stale_after_s": 30.0},
    )
    with Probe("health_probe") as probe:
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        r = Rig(probe, {}, {})
        for tid in IDS:
            r.diag_pubs[tid] = probe.node.create_publisher(
                Diagnosis, f"/thruster/{tid}/fdd/diagnosis", 10
            )
            r.res_pubs[tid] = probe.node.create_publisher(
                Residual, f"/thruster/{tid}/fdd/residual", reliable
            )
        probe.node.create_subscription(
            VehicleHealth, "/thruster_fdd/health", r.health.append, latched
        )
        probe.node.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda m: r.statuses.extend(s for s in m.status if s.name == "thruster_fdd: health"),
            reliable,
        )
        try:
            matched = probe.spin_until(
                lambda: (
                    all(p.get_subscription_count() > 0 for p in r.res_pubs.values())
                    and all(p.get_subscription_count() > 0 for p in r.diag_pubs.values())
                ),
                30.0,
                0.1,
            )
            assert matched, "the health node never subscribed"
            yield r
        finally:
            stop_children({"health": proc}, timeout_s=10.0)


def _finite(msg) -> bool:
    return all(
        math.isfinite(v)
        for t in msg.thrusters
        for v in (t.confidence, t.effectiveness, t.effectiveness_std, t.fitted_severity)
    )


def test_before_any_diagnosis_every_thruster_is_stale_and_unknown(rig: Rig) -> None:
    assert rig.probe.spin_until(lambda: rig.health, 10.0)
    msg = rig.health[-1]
    assert [t.thruster_id for t in msg.thrusters] == list(IDS)
    assert all(t.stale and t.label == "unknown" and not t.faulty for t in msg.thrusters)
    assert msg.stale_mask == 0b11
    assert msg.faulty_mask == 0
    assert all(t.effectiveness == 1.0 and t.effectiveness_std == 0.5 for t in msg.thrusters)
    assert _finite(msg)


def test_a_fault_is_flagged_at_once_with_its_effectiveness(rig: Rig) -> None:
    from thruster_fdd_msgs.msg import ThrusterHealth

    # Two blades lost on an unseen unit; the healthy twin (same seed and commands) gives the truth.
    config = load_config("t100")
    t, command = make_signal("multilevel", 120.0, 10.0, seed=4321)
    spec = severity_spec("blades", 2.0)
    faulty = simulate(config, t, command, "broken_blade_2", seed=4321, spec=spec)
    healthy = simulate(config, t, command, "nominal_15v", seed=4321)
    rig.residuals("h0", 7000.0, faulty.command, faulty.voltage, faulty.rpm, faulty.current)
    window = slice(len(t) - 300, len(t))
    t_f, t_h = faulty.extra["thrust"][window], healthy.extra["thrust"][window]
    truth = float(t_f @ t_h / (t_h @ t_h))
    rig.probe.spin(0.5)
    n = len(rig.health)
    rig.diagnosis("h0", "broken_blade_2", 0.97)
    # The period is 5 s: a message within 2 s is the one published on the change.
    assert rig.probe.spin_until(lambda: len(rig.health) > n, 2.0), [
        (kv.key, kv.value) for kv in rig.statuses[-1].values
    ]
    msg = rig.health[-1]
    h0, h1 = msg.thrusters
    assert h0.label == "broken_blade_2"
    assert h0.faulty
    assert not h0.stale
    assert h0.condition == 5
    assert h0.confidence == pytest.approx(0.97)
    assert msg.faulty_mask == 0b01
    assert msg.stale_mask == 0b10
    assert h1.stale
    assert not h1.faulty
    assert h0.effectiveness_source == ThrusterHealth.ESTIMATED
    assert h0.fitted_fault == "blades"
    assert abs(h0.effectiveness - truth) < 0.1, (h0.effectiveness, truth)
    assert 0.0 < h0.effectiveness_std < 0.3
    assert _finite(msg)


def test_a_late_subscriber_gets_the_latest_health(rig: Rig) -> None:
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from thruster_fdd_msgs.msg import VehicleHealth

    late: list = []
    qos = QoSProfile(
        depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
    )
    sub = rig.probe.node.create_subscription(
        VehicleHealth, "/thruster_fdd/health", late.append, qos
    )
    try:
        assert rig.probe.spin_until(lambda: late, 3.0), "transient local: the last one at once"
        assert late[0].thrusters[0].label == "broken_blade_2"
    finally:
        rig.probe.node.destroy_subscription(sub)


def test_status_names_the_vehicle_and_each_thrusters_effectiveness(rig: Rig) -> None:
    n = len(rig.statuses)
    assert rig.probe.spin_until(lambda: len(rig.statuses) > n, 5.0)
    status = rig.statuses[-1]
    assert status.hardware_id == "vehicle"
    values = {kv.key: kv.value for kv in status.values}
    assert values["thrusters"] == "h0,h1"
    assert "h0.effectiveness" in values
    assert "h1.effectiveness" in values
    assert "h1" in status.message  # h1 has no diagnoses


def test_effectiveness_is_a_ratio_of_thrust_not_of_a_label(rig: Rig) -> None:
    # A healthy thruster on h1 named nominal: its effectiveness comes from its own load.
    config = load_config("t100")
    t, command = make_signal("multilevel", 90.0, 10.0, seed=4322)
    trace = simulate(config, t, command, "nominal_15v", seed=4322)
    rig.residuals("h1", 9000.0, trace.command, trace.voltage, trace.rpm, trace.current)
    rig.diagnosis("h1", "nominal_15v")
    n = len(rig.health)
    assert rig.probe.spin_until(lambda: len(rig.health) > n, 2.0)
    h1 = rig.health[-1].thrusters[1]
    assert not h1.faulty
    assert not h1.stale
    assert abs(h1.effectiveness - 1.0) < 0.08
    assert np.isfinite(h1.effectiveness_std)
