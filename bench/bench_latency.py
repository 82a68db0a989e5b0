"""Benchmark: end-to-end latency from telemetry received to diagnosis published, live.

Runs ``thruster-fdd up`` (simulated thrusters, models, no recorder) and listens to every
thruster's ``fdd/diagnosis``. A diagnosis carries the header stamp of the telemetry sample that
closed its window — the time the ESC driver received that frame — and DDS gives each message
its source timestamp, the time it was published. So "published" is the chain driver ->
nominal_model -> classifier up to the classifier's publish call (the target), "received" adds
the hop to a subscriber (this one). The same is measured at the telemetry and residual topics,
to show where the time goes. Prints median, p95 and p99 over all messages after a warm-up.

Usage (after ``. scripts/bootstrap.sh``): ``python bench/bench_latency.py --thrusters 4``
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import time
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from thruster_fdd_msgs.msg import Diagnosis, EscTelemetry, Residual

from thruster_fdd.nodes.common import NO_SUB_EVENTS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--thrusters", type=int, default=4)
    parser.add_argument("--rate", type=float, default=50.0, help="telemetry rate, Hz")
    parser.add_argument("--seconds", type=float, default=60.0, help="measured interval, s")
    parser.add_argument("--warmup", type=float, default=30.0, help="first window fills, s")
    parser.add_argument(
        "--observer-nice",
        type=int,
        default=0,
        help="niceness of this listening process once up has started (the published latencies "
        "use DDS source timestamps, so they do not depend on when the listener runs)",
    )
    args = parser.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    up = subprocess.Popen(
        ["thruster-fdd", "up", "--thrusters", str(args.thrusters), "--rate", str(args.rate),
         "--no-record", "--print-period", "1000", "--signal", "multilevel",
         "--duration", str(args.warmup + args.seconds + 5)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    os.nice(args.observer_nice)
    rclpy.init()
    node = rclpy.create_node("bench_latency")
    stages = ("telemetry", "residual", "diagnosis")
    latencies_ms: dict[str, list[float]] = {stage: [] for stage in stages}
    published_ms: dict[str, list[float]] = {stage: [] for stage in stages}
    start = time.monotonic()

    def listener(stage: str) -> Callable[[Any, dict[str, int]], None]:
        def on_message(msg: Any, info: dict[str, int]) -> None:
            if time.monotonic() - start < args.warmup:
                return
            if stage == "diagnosis" and msg.confidence == 0.0:
                return  # the UNKNOWN a silent classifier says on its own clock
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            latencies_ms[stage].append((node.get_clock().now().nanoseconds - stamp_ns) / 1e6)
            published_ms[stage].append((info["source_timestamp"] - stamp_ns) / 1e6)

        return on_message

    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    for i in range(args.thrusters):
        ns = f"/thruster/t{i}"
        for msg_type, topic, stage, qos in (
            (EscTelemetry, "esc/telemetry", "telemetry", qos_profile_sensor_data),
            (Residual, "fdd/residual", "residual", reliable),
            (Diagnosis, "fdd/diagnosis", "diagnosis", reliable),
        ):
            # Without QoS event handlers, as the nodes: less of the observer's own load.
            node.create_subscription(
                msg_type, f"{ns}/{topic}", listener(stage), qos, event_callbacks=NO_SUB_EVENTS
            )
    while time.monotonic() - start < args.warmup + args.seconds:
        rclpy.spin_once(node, timeout_sec=0.1)
    up.send_signal(signal.SIGINT)
    up.wait(timeout=60)
    node.destroy_node()
    rclpy.shutdown()
    if not latencies_ms["diagnosis"]:
        raise SystemExit("no diagnosis received")
    print(
        f"{args.thrusters} thruster(s) at {args.rate:g} Hz, load average "
        f"{os.getloadavg()[0]:.2f}; latency from telemetry received by the ESC driver:"
    )
    for stage in stages:
        for what, values in (("published", published_ms[stage]), ("received", latencies_ms[stage])):
            ordered = sorted(values)
            p = [ordered[min(len(ordered) - 1, int(q * len(ordered)))] for q in (0.95, 0.99)]
            print(
                f"  -> {stage:9s} {what:9s}: median {statistics.median(ordered):.2f} ms, "
                f"p95 {p[0]:.2f} ms, p99 {p[1]:.2f} ms, max {ordered[-1]:.2f} ms ({len(ordered)})"
            )


if __name__ == "__main__":
    main()
