"""Benchmark: messages per second the recorder node keeps without drops, and its CPU share.

Starts the recorder node as its own process, publishes ``EscTelemetry`` on ``--topics``
topics at a total of ``--rate`` messages per second for ``--seconds`` from this process
(reliable QoS, so the recorder subscribes reliably), stops the recorder with SIGINT and counts
what its MCAP files hold. CPU share = the recorder process's user+system time over wall time.
Repeats and prints the median.

Usage (after ``. scripts/bootstrap.sh``)::

    python bench/bench_recorder.py --rate 5000 --topics 24 --seconds 10 --repeats 3
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from mcap.reader import make_reader
from procstat import cpu_seconds
from rclpy.qos import QoSProfile, ReliabilityPolicy
from results_file import Run, add_results_option
from thruster_fdd_msgs.msg import EscTelemetry


def run_once(rate: float, topics: int, seconds: float) -> tuple[int, int, float]:
    """Published count, recorded count and recorder CPU share (1.0 = one core)."""
    out = Path(tempfile.mkdtemp(prefix="bench_recorder_"))
    recorder = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "thruster_fdd.nodes.recorder",
            "--ros-args",
            "-p",
            f"output_dir:={out}",
            "-p",
            "discovery_period_s:=0.2",
            "-p",
            "prefix:=bench",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    node = rclpy.create_node("bench_publisher")
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = [
        node.create_publisher(EscTelemetry, f"/thruster/b{i}/esc/telemetry", qos)
        for i in range(topics)
    ]
    deadline = time.monotonic() + 20
    while any(p.get_subscription_count() == 0 for p in pubs) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    msg = EscTelemetry(thruster_id="b", voltage_v=15.0, rpm=1234.0, current_a=2.5)
    sent = 0
    cpu0, wall0 = cpu_seconds(recorder.pid), time.monotonic()
    next_t = wall0
    period = topics / rate
    while time.monotonic() - wall0 < seconds:
        for pub in pubs:
            msg.sequence = sent
            pub.publish(msg)
            sent += 1
        next_t += period
        delay = next_t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    time.sleep(1.0)
    cpu_share = (cpu_seconds(recorder.pid) - cpu0) / (time.monotonic() - wall0)
    recorder.send_signal(signal.SIGINT)
    recorder.wait(timeout=30)
    node.destroy_node()
    recorded = 0
    for path in out.rglob("*.mcap"):  # the bag folder <out>/bench/ holds the files
        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
            recorded += sum(
                count
                for channel_id, count in summary.statistics.channel_message_counts.items()
                if summary.channels[channel_id].topic.startswith("/thruster/b")
            )
    return sent, recorded, cpu_share


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=5000.0, help="total messages per second")
    parser.add_argument("--topics", type=int, default=24, help="topics (8 thrusters x 3)")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--repeats", type=int, default=3)
    add_results_option(parser)
    args = parser.parse_args()
    run = Run("bench_recorder")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rclpy.init()
    results = [run_once(args.rate, args.topics, args.seconds) for _ in range(args.repeats)]
    rclpy.shutdown()
    for sent, recorded, cpu in results:
        print(f"  sent {sent}, recorded {recorded} ({recorded / sent:.2%}), recorder CPU {cpu:.0%}")
    achieved = statistics.median(sent / args.seconds for sent, _, _ in results)
    kept = statistics.median(recorded / sent for sent, recorded, _ in results)
    cpu = statistics.median(cpu for _, _, cpu in results)
    print(
        f"recorder: offered {achieved:.0f} msg/s on {args.topics} topics, kept {kept:.2%} "
        f"(median of {args.repeats}), recorder CPU {cpu:.0%} of one core"
    )
    run.add(f"messages offered on {args.topics} topics", "msg/s", achieved)
    run.add("share of offered messages recorded", "fraction", kept,
            min=min(r / s for s, r, _ in results))  # fmt: skip
    run.add("recorder CPU", "cores", cpu)
    run.write(args.results, repeats=args.repeats)


if __name__ == "__main__":
    main()
