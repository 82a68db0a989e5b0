"""No published float is ever non-finite, checked on the messages themselves.

``residual_message`` (what ``nominal_model`` publishes) on any telemetry, property-based; then
a real graph: ``nominal_model`` and ``classifier`` nodes fed telemetry with NaN, inf, huge
values and jumps in time, whose every Residual, Diagnosis and /diagnostics value is checked.
The ESC driver's EscTelemetry is checked in test_esc_driver.py, after every link fault.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from probe import Probe, non_finite_fields, start_node

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.core.nominal.residuals import ResidualStream
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd.lifetime import stop_children

MODELS = default_models_dir()
NS = "/thruster/adv"
extreme = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 1e154, 0.0]),
    st.floats(-20, 20),
)


@pytest.fixture(scope="module")
def model() -> NominalModel:
    return NominalModel.load(MODELS / "nominal")


@settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(rows=st.lists(st.tuples(extreme, extreme, extreme, extreme, extreme), max_size=60))
def test_residual_message_is_finite_on_any_telemetry(
    model: NominalModel, rows: list[tuple[float, ...]]
) -> None:
    from thruster_fdd_msgs.msg import EscTelemetry, Residual

    from thruster_fdd.nodes.nominal_model import residual_message

    stream = ResidualStream(model)
    for i, (command, voltage, rpm, current, jitter) in enumerate(rows):
        # Mostly a plausible stream (so predictions are made), with the extremes in between.
        plausible = i % 3 != 0
        telemetry = EscTelemetry(
            command=0.3 if plausible else command,
            voltage_v=15.0 if plausible else voltage,
            rpm=1500.0 if plausible else rpm,
            current_a=2.0 if plausible else current,
        )
        t = i * 0.1 + (jitter if math.isfinite(jitter) and i % 5 == 0 else 0.0)
        out = stream.push(t, telemetry.command, telemetry.voltage_v, telemetry.rpm,
                          telemetry.current_a, i)  # fmt: skip
        if out is None:
            continue
        msg = residual_message("adv", model.model_id, telemetry, out)
        assert non_finite_fields(msg) == []
        if not all(math.isfinite(v) for v in (command, voltage, rpm, current)) and not plausible:
            assert msg.flags & Residual.INPUT_INVALID


@pytest.fixture(scope="module")
def graph() -> Iterator[Probe]:
    procs = {
        "nominal": start_node(
            "nominal_model",
            NS,
            {"thruster_id": "adv", "model_dir": MODELS / "nominal", "reliable_telemetry": "true",
             "diagnostics_period_s": 0.5},
        ),
        "classifier": start_node(
            "classifier",
            NS,
            {"thruster_id": "adv", "model_dir": MODELS / "classifier", "diagnostics_period_s": 0.5,
             "stale_after_s": 60.0},
        ),
    }  # fmt: skip
    probe = Probe("adversarial_probe")
    try:
        yield probe
    finally:
        stop_children(procs, timeout_s=10.0)
        probe.close()


@pytest.mark.ros
def test_nodes_never_publish_a_non_finite_field(graph: Probe) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from thruster_fdd_msgs.msg import Diagnosis, EscTelemetry, Residual

    reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    node = graph.node
    got: dict[str, list[Any]] = {"residual": [], "diagnosis": [], "status": []}
    subs = [
        node.create_subscription(Residual, f"{NS}/fdd/residual", got["residual"].append, reliable),
        node.create_subscription(
            Diagnosis, f"{NS}/fdd/diagnosis", got["diagnosis"].append, reliable
        ),
    ]
    node.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda m: got["status"].extend(s for s in m.status if s.name.endswith(" adv")),
        reliable,
    )
    pub = node.create_publisher(EscTelemetry, f"{NS}/esc/telemetry", reliable)
    # Every endpoint matched before the first sample (a loaded machine matches slowly).
    assert graph.spin_until(
        lambda: (
            pub.get_subscription_count() >= 1
            and all(sub.get_publisher_count() >= 1 for sub in subs)
        ),
        60.0,
    ), "the model nodes did not come up"
    graph.spin(1.0)  # the classifier's own match with the residuals
    bad = [math.nan, math.inf, -math.inf, 1e308, -1e308]
    n = 500
    for i in range(n):
        msg = EscTelemetry(thruster_id="adv", sequence=i, command=0.4, voltage_v=15.0,
                           rpm=2000.0, current_a=2.5, temperature_c=20.0)  # fmt: skip
        if i >= 260 and i % 10 == 9:  # after a clean 26 s, one sample in ten NaN, inf or huge
            field = ("command", "voltage_v", "rpm", "current_a")[(i // 10) % 4]
            setattr(msg, field, bad[(i // 40) % len(bad)])
        t_ns = 1_000_000_000 + i * 100_000_000 + (50_000_000_000 if i == 300 else 0)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t_ns, 1_000_000_000)
        pub.publish(msg)
        if i % 50 == 0:
            graph.spin(0.01)
    assert graph.spin_until(lambda: len(got["residual"]) >= n, 30.0), len(got["residual"])
    assert graph.spin_until(lambda: len(got["diagnosis"]) >= 3, 30.0), len(got["diagnosis"])
    graph.spin(1.2)  # a status of each node after all of it
    assert sum(1 for r in got["residual"] if r.flags & Residual.INPUT_INVALID) >= 20
    for kind in ("residual", "diagnosis"):
        offenders = [(i, non_finite_fields(m)) for i, m in enumerate(got[kind])]
        assert [o for o in offenders if o[1]] == [], f"non-finite {kind} fields"
    names = {s.name for s in got["status"]}
    assert {"thruster_fdd: nominal_model adv", "thruster_fdd: classifier adv"} <= names
    for status in got["status"]:
        for kv in status.values:
            try:
                number = float(kv.value)
            except ValueError:
                continue
            assert math.isfinite(number), f"{status.name}: {kv.key}={kv.value}"
