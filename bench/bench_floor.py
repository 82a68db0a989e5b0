"""Benchmark: the CPU floor of the vehicle set's ROS traffic alone, with nothing else done.

The target is the vehicle set (drivers, models, health, recorder) at 8 thrusters x 50 Hz
within 0.2 cores. Whatever the nodes compute, they publish and take the contracted topics
(docs/contracts.md) through rclpy and Fast DDS, and the recorder takes every one of them. This
script measures that traffic by itself, in three processes of bare rclpy nodes that do no
other work:

- ``vehicle``: one node publishing, per thruster, ``esc/telemetry`` at the telemetry rate,
  ``fdd/residual`` at the model rate, ``fdd/diagnosis`` and three ``/diagnostics`` statuses
  once a second, one ``/thruster_fdd/health`` a second, and taking ``esc/command`` (the
  least wake-up structure: one timer at the telemetry rate for all thrusters, where the real
  drivers publish on each serial frame);
- ``recorder``: one node taking every one of those topics raw (as the recorder does; no file
  written);
- ``commands``: the simulation harness's command players (not part of the vehicle set).

The message rates, QoS and types are those of ``thruster-fdd up`` (counted in the bag of a 40 s
run at 8 thrusters x 50 Hz: about 400 telemetry, 160 command, 80 residual, 24 status, 4
diagnosis and 1.5 health messages a second; this script sends a diagnosis per thruster each
second). By default every telemetry message has a wake of its own, the thrusters evenly out of
phase, as independent serial links deliver them; ``--burst`` publishes all thrusters' messages
of a period in one wake (the least the traffic can cost). Each role runs the executor of
``nodes.common.make_executor`` (``THRUSTER_FDD_EXECUTOR`` applies). Printed: CPU cores (CPU
seconds per wall second after the warm-up) of the vehicle and recorder processes and their sum,
the messages the recorder took per second, medians over ``--repeats``.

Usage (after ``. scripts/bootstrap.sh``)::

    python bench/bench_floor.py --thrusters 1 8 --seconds 15 --warmup 5 --repeats 3
"""

from __future__ import annotations

import argparse
import signal
import statistics
import subprocess
import sys
import time
from typing import Any

from procstat import cpu_seconds
from results_file import Run, add_results_option

RESIDUAL_HZ = 10.0
COMMAND_HZ = 20.0
STATUSES_PER_THRUSTER = 3  # driver, model and classifier, once a second each
MODEL = "nominal-narx_deadband-0d46350029a7"
CLASSES = (
    "nominal_15v", "nominal_13v", "nominal_11v8", "broken_blade_1", "broken_blade_2", "biofouling"
)  # fmt: skip


def _role(role: str, thrusters: int, rate: float, burst: bool) -> None:
    """Run one role until SIGINT; the recorder prints the messages it took."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import qos_profile_sensor_data
    from thruster_fdd_msgs.msg import (
        Diagnosis,
        EscTelemetry,
        Residual,
        ThrusterCommand,
        ThrusterHealth,
        VehicleHealth,
    )

    from thruster_fdd.nodes.common import (
        NO_PUB_EVENTS,
        NO_SUB_EVENTS,
        RELIABLE_10,
        init_rclpy,
        make_executor,
        spin,
    )
    from thruster_fdd.nodes.health import HEALTH_QOS, HEALTH_TOPIC
    from thruster_fdd.nodes.nominal_model import RESIDUAL_QOS

    init_rclpy([sys.argv[0]])
    node = rclpy.create_node(f"floor_{role}")
    ids = [f"t{i}" for i in range(thrusters)]
    topics: list[tuple[type, str, Any]] = [(DiagnosticArray, "/diagnostics", RELIABLE_10)]
    topics.append((VehicleHealth, HEALTH_TOPIC, HEALTH_QOS))
    for tid in ids:
        ns = f"/thruster/{tid}"
        topics += [
            (EscTelemetry, f"{ns}/esc/telemetry", qos_profile_sensor_data),
            (Residual, f"{ns}/fdd/residual", RESIDUAL_QOS),
            (Diagnosis, f"{ns}/fdd/diagnosis", RELIABLE_10),
        ]
    commands = [(ThrusterCommand, f"/thruster/{tid}/esc/command", RELIABLE_10) for tid in ids]
    taken = [0]

    def count(_msg: object) -> None:
        taken[0] += 1

    if role == "recorder":
        for msg_type, topic, qos in [*topics, *commands]:
            node.create_subscription(
                msg_type, topic, count, qos, raw=True, event_callbacks=NO_SUB_EVENTS
            )
    elif role == "commands":
        pubs = [
            node.create_publisher(t, n, q, event_callbacks=NO_PUB_EVENTS) for t, n, q in commands
        ]

        def command() -> None:
            for pub in pubs:
                pub.publish(ThrusterCommand(command=0.3))

        node.create_timer(1.0 / COMMAND_HZ, command)
    else:
        pubs = {
            n: node.create_publisher(t, n, q, event_callbacks=NO_PUB_EVENTS) for t, n, q in topics
        }
        for msg_type, topic, qos in commands:
            node.create_subscription(msg_type, topic, count, qos, event_callbacks=NO_SUB_EVENTS)
        every = max(round(rate / RESIDUAL_HZ), 1)
        per_second = max(round(rate), 1)

        def publish_one(tid: str, k: int) -> None:
            """Thruster ``tid``'s messages of its ``k``-th telemetry period."""
            ns = f"/thruster/{tid}"
            now = node.get_clock().now().to_msg()
            msg = EscTelemetry(thruster_id=tid, rpm=1500.0, current_a=2.0, voltage_v=15.0)
            msg.header.stamp = now
            pubs[f"{ns}/esc/telemetry"].publish(msg)
            if k % every == 0:
                res = Residual(thruster_id=tid, command=0.3, voltage_v=15.0, model_id=MODEL)
                res.header.stamp = now
                pubs[f"{ns}/fdd/residual"].publish(res)
            if k % per_second == 0:
                diag = Diagnosis(
                    thruster_id=tid,
                    label="nominal_15v",
                    class_names=list(CLASSES),
                    probabilities=[0.9, 0.02, 0.02, 0.02, 0.02, 0.02],
                    confidence=0.9,
                    model_id=MODEL,
                )
                diag.header.stamp = now
                pubs[f"{ns}/fdd/diagnosis"].publish(diag)
                for task in range(STATUSES_PER_THRUSTER):
                    status = DiagnosticStatus(
                        name=f"thruster_fdd: task{task} {tid}",
                        message="ok",
                        values=[KeyValue(key="rate_hz", value="50.0")] * 6,
                    )
                    pubs["/diagnostics"].publish(DiagnosticArray(status=[status]))
                if tid == ids[0]:
                    health = VehicleHealth(thrusters=[ThrusterHealth(thruster_id=t) for t in ids])
                    pubs[HEALTH_TOPIC].publish(health)

        tick = [0]
        if burst:

            def publish_all() -> None:
                for tid in ids:
                    publish_one(tid, tick[0])
                tick[0] += 1

            node.create_timer(1.0 / rate, publish_all)
        else:
            # One wake per message, the thrusters' periods evenly out of phase (as independent
            # serial links deliver their frames).
            def publish_next() -> None:
                k, i = divmod(tick[0], len(ids))
                publish_one(ids[i], k)
                tick[0] += 1

            node.create_timer(1.0 / (rate * len(ids)), publish_next)
    executor = make_executor()
    executor.add_node(node)
    t0 = time.monotonic()
    try:
        spin(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if role == "recorder":
            print(taken[0] / (time.monotonic() - t0), flush=True)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def run_once(
    thrusters: int, rate: float, seconds: float, warmup: float, burst: bool
) -> dict[str, float] | None:
    """One run of the three roles; cores of vehicle and recorder, messages a second taken
    (None when a role had to be killed)."""
    procs = {
        role: subprocess.Popen(
            [
                sys.executable,
                __file__,
                "--role",
                role,
                "--thrusters",
                str(thrusters),
                "--rate",
                str(rate),
                *(["--burst"] if burst else []),
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        for role in ("recorder", "commands", "vehicle")
    }
    time.sleep(warmup)
    first = {r: cpu_seconds(p.pid) for r, p in procs.items()}
    t0 = time.monotonic()
    time.sleep(seconds)
    last = {r: cpu_seconds(p.pid) for r, p in procs.items()}
    wall = time.monotonic() - t0
    for p in procs.values():
        p.send_signal(signal.SIGINT)
    out = {r: (last[r] - first[r]) / wall for r in ("vehicle", "recorder")}
    try:
        text, _ = procs["recorder"].communicate(timeout=30)
        for p in procs.values():
            p.wait(timeout=30)
    except subprocess.TimeoutExpired:
        # A role that ignores Ctrl-C must not outlive the run (and load the next one).
        for p in procs.values():
            p.kill()
            p.wait(timeout=10)
        print(f"  a role did not stop within 30 s of Ctrl-C at {thrusters} thrusters: run dropped")
        return None
    out["taken_per_s"] = float(text.split()[-1])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--thrusters", type=int, nargs="+", default=[1, 8], help="thruster counts (default 1 8)"
    )
    parser.add_argument("--rate", type=float, default=50.0, help="telemetry rate, Hz (default 50)")
    parser.add_argument(
        "--seconds", type=float, default=15.0, help="measured interval, s (default 15)"
    )
    parser.add_argument(
        "--warmup", type=float, default=5.0, help="warm-up before it, s (default 5)"
    )
    parser.add_argument("--repeats", type=int, default=3, help="runs per count (default 3)")
    parser.add_argument(
        "--burst",
        action="store_true",
        help="publish every thruster's telemetry in one wake per period (default: one wake per "
        "message, the thrusters out of phase, as independent serial links deliver)",
    )
    parser.add_argument(
        "--role", choices=("vehicle", "recorder", "commands"), help=argparse.SUPPRESS
    )
    add_results_option(parser)
    args = parser.parse_args()
    if args.role:
        _role(args.role, args.thrusters[0], args.rate, args.burst)
        return
    run = Run("bench_floor")
    print(f"{'thrusters':>9} {'vehicle':>8} {'recorder':>9} {'sum':>6} {'taken/s':>8}  (cores)")
    for n in args.thrusters:
        tried = [
            run_once(n, args.rate, args.seconds, args.warmup, args.burst)
            for _ in range(args.repeats)
        ]
        runs = [r for r in tried if r is not None]
        if not runs:
            continue
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        sums = [r["vehicle"] + r["recorder"] for r in runs]
        each = ", ".join(f"{x:.3f}" for x in sums)
        print(
            f"{n:9d} {med['vehicle']:8.3f} {med['recorder']:9.3f} {statistics.median(sums):6.3f} "
            f"{med['taken_per_s']:8.0f}  (sums of the runs: {each})",
            flush=True,
        )
        run.add(f"bare rclpy set, {n} thrusters x {args.rate:g} Hz", "cores",
                statistics.median(sums), vehicle=med["vehicle"], recorder=med["recorder"],
                taken_per_s=med["taken_per_s"], runs=len(runs))  # fmt: skip
    run.write(args.results, burst=args.burst)


if __name__ == "__main__":
    main()
