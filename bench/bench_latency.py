"""Benchmark: end-to-end latency from telemetry received to diagnosis published, live.

Runs ``thruster-fdd up`` (simulated thrusters, models, recording as by default) and listens to every
thruster's ``fdd/diagnosis``. A diagnosis carries the header stamp of the telemetry sample that
closed its window — the time the ESC driver received that frame — and DDS gives each message
its source timestamp, the time it was published. So "published" is the chain driver ->
nominal_model -> classifier up to the classifier's publish call (the target), "received" adds
the hop to a subscriber (this one). The same is measured at the telemetry and residual topics,
to show where the time goes. Prints median, p95 and p99 over all messages after a warm-up.

With ``--baseline SRC`` every configuration also runs from another source tree of the package
(e.g. ``git archive <commit>`` of an earlier version, through ``PYTHONPATH``), interleaved with
this one (A then B, ``--repeats`` times), so both see the same machine load.

Usage (after ``. scripts/bootstrap.sh``)::

    python bench/bench_latency.py --thrusters 1 4 8 --seconds 60 --baseline /tmp/base
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from results_file import Run, add_results_option
from thruster_fdd_msgs.msg import Diagnosis, EscTelemetry, Residual

from thruster_fdd.nodes.common import NO_SUB_EVENTS, make_executor, spin_until

STAGES = ("telemetry", "residual", "diagnosis")


def run_once(
    thrusters: int, rate: float, seconds: float, warmup: float, source: str | None
) -> dict[str, dict[str, list[float]]]:
    """Run one configuration; latencies in ms by what ("published", "received") and stage."""
    env = dict(os.environ)
    if source:
        env["PYTHONPATH"] = ":".join(
            [
                f"{source}/src/thruster_fdd",
                f"{source}/src/thruster_fdd_shore",
                env.get("PYTHONPATH", ""),
            ]
        )
    record_dir = tempfile.mkdtemp(prefix="bench_latency_")
    up = subprocess.Popen(
        [sys.executable, "-m", "thruster_fdd_shore.cli", "up", "--thrusters", str(thrusters),
         "--rate", str(rate), "--record-dir", record_dir, "--print-period", "1000",
         "--signal", "multilevel", "--duration", str(warmup + seconds + 5)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )  # fmt: skip
    context = Context()
    rclpy.init(context=context)
    node = Node("bench_latency", context=context)
    out: dict[str, dict[str, list[float]]] = {
        what: {stage: [] for stage in STAGES} for what in ("published", "received")
    }
    start = time.monotonic()

    def listener(stage: str) -> Callable[[Any, Any], None]:
        def on_message(msg: Any, info: Any) -> None:
            if time.monotonic() - start < warmup:
                return
            if stage == "diagnosis" and msg.confidence == 0.0:
                return  # the UNKNOWN a silent classifier says on its own clock
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            out["received"][stage].append((time.time_ns() - stamp_ns) / 1e6)
            out["published"][stage].append((info["source_timestamp"] - stamp_ns) / 1e6)

        return on_message

    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    for i in range(thrusters):
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
    # Not the EventsExecutor: rclpy 7.1.6's passes (message, info) as one argument to
    # callbacks that take the message info (docs/development.md).
    executor = make_executor("single", context=context)
    executor.add_node(node)
    spin_until(executor, lambda: False, start + warmup + seconds)
    up.send_signal(signal.SIGINT)
    up.wait(timeout=60)
    shutil.rmtree(record_dir, ignore_errors=True)
    executor.shutdown(timeout_sec=1.0)
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    return out


def stats(values: list[float]) -> dict[str, float]:
    """Median, p95, p99, max and count of ``values`` (ms); empty when there are none."""
    if not values:
        return {}
    ordered = sorted(values)
    p95, p99 = (ordered[min(len(ordered) - 1, int(q * len(ordered)))] for q in (0.95, 0.99))
    return {
        "median": statistics.median(ordered),
        "p95": p95,
        "p99": p99,
        "max": ordered[-1],
        "count": len(ordered),
    }


def summary(values: list[float]) -> str:
    """Median, p95, p99 and max of ``values`` (ms) and their count, as text."""
    s = stats(values)
    if not s:
        return "none"
    return (
        f"median {s['median']:.2f} ms, p95 {s['p95']:.2f} ms, p99 {s['p99']:.2f} ms, "
        f"max {s['max']:.2f} ms ({s['count']})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--thrusters", type=int, nargs="+", default=[1, 4, 8])
    parser.add_argument("--rate", type=float, default=50.0, help="telemetry rate, Hz")
    parser.add_argument("--seconds", type=float, default=60.0, help="measured interval, s")
    parser.add_argument("--warmup", type=float, default=30.0, help="first window fills, s")
    parser.add_argument(
        "--baseline", metavar="SRC", help="source tree of the layout to compare with (A/B)"
    )
    parser.add_argument("--repeats", type=int, default=1, help="A/B pairs per configuration")
    parser.add_argument(
        "--all-stages",
        action="store_true",
        help="also print the telemetry and residual stages and the received latencies",
    )
    add_results_option(parser)
    args = parser.parse_args()
    run = Run("bench_latency")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    for n in args.thrusters:
        for _ in range(args.repeats):
            runs = [("baseline", args.baseline)] if args.baseline else []
            for label, source in [*runs, ("this", None)]:
                load = os.getloadavg()[0]
                out = run_once(n, args.rate, args.seconds, args.warmup, source)
                print(
                    f"{label:8s} {n} x {args.rate:g} Hz, load {load:.1f}: diagnosis published "
                    f"{summary(out['published']['diagnosis'])}",
                    flush=True,
                )
                if s := stats(out["published"]["diagnosis"]):
                    median = s.pop("median")
                    run.add(
                        f"telemetry received -> diagnosis published, {n} thrusters x "
                        f"{args.rate:g} Hz ({label})", "ms", median, load=load, **s,
                    )  # fmt: skip
                if args.all_stages:
                    for stage in STAGES:
                        for what in ("published", "received"):
                            print(f"    -> {stage:9s} {what:9s}: {summary(out[what][stage])}")

    run.write(args.results)


if __name__ == "__main__":
    main()
