"""Benchmark: end-to-end latency from telemetry received to diagnosis published, live.

Runs ``thruster-fdd up`` (simulated thrusters, models, no recorder) and listens to every
thruster's ``fdd/diagnosis``. A diagnosis carries the header stamp of the telemetry sample that
closed its window — the time the ESC driver received that frame — so arrival time minus stamp
is the whole chain: driver -> nominal_model -> classifier -> this subscriber. Prints median,
p95 and p99 over all decisions after a warm-up.

Usage (after ``. scripts/bootstrap.sh``): ``python bench/bench_latency.py --thrusters 4``
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import time

import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from thruster_fdd_msgs.msg import Diagnosis


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--thrusters", type=int, default=4)
    parser.add_argument("--rate", type=float, default=50.0, help="telemetry rate, Hz")
    parser.add_argument("--seconds", type=float, default=60.0, help="measured interval, s")
    parser.add_argument("--warmup", type=float, default=30.0, help="first window fills, s")
    args = parser.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    up = subprocess.Popen(
        ["thruster-fdd", "up", "--thrusters", str(args.thrusters), "--rate", str(args.rate),
         "--no-record", "--print-period", "1000", "--signal", "multilevel",
         "--duration", str(args.warmup + args.seconds + 5)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    rclpy.init()
    node = rclpy.create_node("bench_latency")
    latencies_ms: list[float] = []
    start = time.monotonic()

    def on_diagnosis(msg: Diagnosis) -> None:
        if time.monotonic() - start < args.warmup or msg.confidence == 0.0:
            return
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        latencies_ms.append((node.get_clock().now().nanoseconds - stamp_ns) / 1e6)

    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    for i in range(args.thrusters):
        node.create_subscription(Diagnosis, f"/thruster/t{i}/fdd/diagnosis", on_diagnosis, qos)
    while time.monotonic() - start < args.warmup + args.seconds:
        rclpy.spin_once(node, timeout_sec=0.1)
    up.send_signal(signal.SIGINT)
    up.wait(timeout=60)
    node.destroy_node()
    rclpy.shutdown()
    if not latencies_ms:
        raise SystemExit("no diagnosis received")
    ordered = sorted(latencies_ms)
    p = [ordered[min(len(ordered) - 1, int(q * len(ordered)))] for q in (0.95, 0.99)]
    print(
        f"{args.thrusters} thrusters at {args.rate:g} Hz, {len(ordered)} decisions: telemetry "
        f"received -> diagnosis received median {statistics.median(ordered):.1f} ms, "
        f"p95 {p[0]:.1f} ms, p99 {p[1]:.1f} ms, max {ordered[-1]:.1f} ms"
    )


if __name__ == "__main__":
    main()
