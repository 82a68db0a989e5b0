"""The model container: its command line, and both model stages of a thruster in one process."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
from probe import Probe

from thruster_fdd.lifetime import stop_children
from thruster_fdd.nodes.container import parse_parameters


def test_parameters_go_to_every_kind_or_to_the_named_one() -> None:
    params = parse_parameters(
        ["nominal_model", "classifier"],
        ["classifier:model_dir=/m/c", "nominal_model:model_dir=/m/n", "diagnostics_period_s=2"],
    )
    as_dict = {k: {p.name: p.value for p in v} for k, v in params.items()}
    assert as_dict == {
        "nominal_model": {"model_dir": "/m/n", "diagnostics_period_s": 2},
        "classifier": {"model_dir": "/m/c", "diagnostics_period_s": 2},
    }


def test_a_value_may_hold_colons() -> None:
    params = parse_parameters(["classifier"], ["classifier:model_dir=/a:b"])
    assert [(p.name, p.value) for p in params["classifier"]] == [("model_dir", "/a:b")]


@pytest.mark.parametrize("text", ["recorder:x=1", "model_dir", "classifier:=1"])
def test_bad_parameters_are_refused_with_the_reason(text: str) -> None:
    with pytest.raises(ValueError, match="-p"):
        parse_parameters(["classifier"], [text])


def test_booleans_are_parsed() -> None:
    params = parse_parameters(["nominal_model"], ["reliable_telemetry=true", "x=False"])
    assert [(p.name, p.value) for p in params["nominal_model"]] == [
        ("reliable_telemetry", True),
        ("x", False),
    ]


@pytest.mark.ros
@pytest.mark.parametrize("intra_process", [True, False], ids=["intra-process", "dds"])
def test_both_stages_in_one_container_diagnose(intra_process: bool) -> None:
    """Telemetry in, residuals out on DDS, diagnoses out; intra-process: the classifier takes
    the residuals from its nominal model, with no fdd/residual subscription of its own; Ctrl-C
    stops every thruster's executor thread and the process exits 0."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from thruster_fdd_msgs.msg import Diagnosis, EscTelemetry, Residual

    from thruster_fdd.nodes.nominal_model import RESIDUAL_QOS
    from thruster_fdd_shore.core.sim.scenario import run_scenario

    # 80 s: the sequential test needs at least 18 s of confident windows past the first 20 s one.
    trace = run_scenario("t100", "broken_blade_2", signal="sine:0.02", duration_s=80, seed=4)
    ns = "/thruster/ct"
    cmd = [sys.executable, "-m", "thruster_fdd.nodes.container", "nominal_model", "classifier"]
    # A second thruster, idle: each thruster spins in its own executor thread.
    cmd += ["--thrusters", "ct", "cx", "-p", "nominal_model:reliable_telemetry=true"]
    # No stale UNKNOWN after the last message: on a loaded machine the probe's spin can overrun
    # and catch it as the last diagnosis (seen once in the full suite).
    cmd += ["-p", "classifier:stale_after_s=60.0"]
    cmd += [] if intra_process else ["--no-intra-process"]
    proc = subprocess.Popen(cmd)
    with Probe("container_probe") as probe:
        node = probe.node
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        residuals: list[Residual] = []
        diagnoses: list[Diagnosis] = []
        node.create_subscription(Residual, f"{ns}/fdd/residual", residuals.append, RESIDUAL_QOS)
        node.create_subscription(Diagnosis, f"{ns}/fdd/diagnosis", diagnoses.append, reliable)
        pub = node.create_publisher(EscTelemetry, f"{ns}/esc/telemetry", reliable)
        try:
            probe.spin_until(
                lambda: bool(
                    pub.get_subscription_count() and node.count_publishers(f"{ns}/fdd/diagnosis")
                ),
                60.0,
                0.1,
            )
            assert pub.get_subscription_count(), "the container never subscribed"
            probe.spin(1.0)
            for i in range(len(trace)):
                msg = EscTelemetry(
                    thruster_id="ct",
                    command=float(trace.command[i]),
                    voltage_v=float(trace.voltage[i]),
                    rpm=float(trace.rpm[i]),
                    current_a=float(trace.current[i]),
                    sequence=i,
                )
                sec, nanosec = divmod((10_000 + i) * 100_000_000, 10**9)  # 10 Hz from 1000 s
                msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
                pub.publish(msg)
                probe.spin(0.003)
            probe.spin_until(lambda: len(residuals) >= len(trace), 15.0, 0.05)
            probe.spin(1.0)  # the last decision follows its residual
            subscribers = node.get_subscriptions_info_by_topic(f"{ns}/fdd/residual")
            classifier_subscribed = any(s.node_name == "classifier" for s in subscribers)
        finally:
            killed = stop_children({"container": proc}, timeout_s=20.0)
    assert killed == [], "the container did not stop on SIGINT"
    assert proc.returncode == 0
    assert len(residuals) == len(trace)
    assert classifier_subscribed is not intra_process
    assert len(diagnoses) >= 10
    assert diagnoses[-1].label == "broken_blade_2"
    assert diagnoses[-1].fault_evidence >= diagnoses[-1].fault_threshold


# Two executors spun by spin_in_threads; a timer of the second raises after 0.3 s.
FAILING = textwrap.dedent(
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from thruster_fdd.nodes.container import spin_in_threads

    def boom():
        raise ZeroDivisionError("boom")

    rclpy.init()
    good, bad = Node("good"), Node("bad")
    good.create_timer(0.1, lambda: None)
    bad.create_timer(0.3, boom)
    executors = [SingleThreadedExecutor(), SingleThreadedExecutor()]
    executors[0].add_node(good)
    executors[1].add_node(bad)
    try:
        spin_in_threads(executors, ["t0", "t1"])
    finally:
        for executor in executors:
            executor.shutdown(timeout_sec=1.0)
    """
)


@pytest.mark.ros
def test_a_callback_that_raises_in_one_thruster_thread_stops_the_container() -> None:
    out = subprocess.run(
        [sys.executable, "-c", FAILING], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 1
    assert "thruster t1: a callback raised ZeroDivisionError('boom')" in out.stderr


@pytest.mark.parametrize("tid", ["tä", "t" * 300])
def test_a_thruster_id_that_is_no_ros_name_is_one_line_exit_2(tid: str) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "thruster_fdd.nodes.container", "esc_driver", "--thrusters", tid],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2, out.stderr
    assert len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert "thruster id" in out.stderr
    assert "Traceback" not in out.stderr
