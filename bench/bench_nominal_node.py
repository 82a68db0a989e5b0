"""Benchmark: per-sample inference time inside the nominal_model node process, and its memory.

Starts the node with the committed model, publishes ``--samples`` telemetry samples 0.1 s apart
in stamp time (so none is decimated away) as fast as the node keeps up, and reads what the node
reports on ``/diagnostics`` each second: median and p99 of its per-sample step (ResidualStream
+ model, measured in the node around the model call) and its resident memory from /proc.

Usage (after ``. scripts/bootstrap.sh``): ``python bench/bench_nominal_node.py --samples 3000``
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile, ReliabilityPolicy
from results_file import Run, add_results_option
from thruster_fdd_msgs.msg import EscTelemetry

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd_shore.core.sim.scenario import run_scenario


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=3000)
    parser.add_argument("--rate", type=float, default=200.0, help="publishing rate, msg/s")
    add_results_option(parser)
    args = parser.parse_args()
    run = Run("bench_nominal_node")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "thruster_fdd.nodes.nominal_model",
            "--ros-args",
            "-r",
            "__ns:=/thruster/bench",
            "-p",
            f"model_dir:={default_models_dir() / 'nominal'}",
            "-p",
            "thruster_id:=bench",
        ],
        stderr=subprocess.DEVNULL,
    )
    rclpy.init()
    node = rclpy.create_node("bench_nominal")
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(EscTelemetry, "/thruster/bench/esc/telemetry", reliable)
    windows: list[dict[str, float]] = []

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == "thruster_fdd: nominal_model bench":
                values = {kv.key: kv.value for kv in status.values}
                if float(values["residual_rate_hz"]) > 0:
                    windows.append({k: float(values[k]) for k in ("median_step_us", "p99_step_us")})

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, reliable)
    while pub.get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.1)
    trace = run_scenario("t100", "nominal_15v", signal="mission", duration_s=args.samples / 10)
    for i in range(len(trace)):
        msg = EscTelemetry(
            command=float(trace.command[i]),
            voltage_v=float(trace.voltage[i]),
            rpm=float(trace.rpm[i]),
            current_a=float(trace.current[i]),
            sequence=i,
        )
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(i * 100_000_000, 1_000_000_000)
        pub.publish(msg)
        rclpy.spin_once(node, timeout_sec=1.0 / args.rate)
    end = time.monotonic() + 2.5
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    rss = _rss_mb(proc.pid)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=10)
    rclpy.shutdown()
    medians = [w["median_step_us"] for w in windows]
    p99s = [w["p99_step_us"] for w in windows]
    print(
        f"nominal_model node, {len(trace)} samples in {len(windows)} one-second windows: "
        f"per-sample step median {statistics.median(medians):.0f} us (median of windows), "
        f"p99 {statistics.median(p99s):.0f} us (median of windows; worst window "
        f"{max(p99s):.0f} us); resident memory {rss:.0f} MB"
    )
    run.add("nominal_model node per-sample step (median of 1 s windows)", "us",
            statistics.median(medians), p99=statistics.median(p99s), worst_p99=max(p99s),
            windows=len(windows))  # fmt: skip
    run.add("nominal_model node resident memory", "MB", rss)
    run.write(args.results, rate_msg_per_s=args.rate, samples=len(trace))


if __name__ == "__main__":
    main()
