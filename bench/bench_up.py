"""Benchmark: CPU and resident memory of the whole `thruster-fdd up` set, by part.

For each (thrusters, rate) pair, runs ``thruster-fdd up`` for ``--seconds`` after a warm-up
(simulated thrusters, recorder on, model nodes when models are exported), samples every process
of the set from /proc, and prints CPU (cores: CPU seconds per wall second over the measured
interval) and resident memory (RSS; PSS, which shares library pages between processes, in
brackets) of

- the vehicle set: ESC drivers, models, health node and recorder — what runs on a vehicle;
- the simulation harness: emulators and command players;
- ``up`` itself (its live table);
- with ``--subscriber``, also a run with one external subscriber to every thruster's
  telemetry (a controller's case: the vehicle's DDS writers then have a reader to serve).

With ``--baseline SRC`` every configuration also runs from another source tree of the package
(e.g. ``git archive <commit>`` of an earlier version, run through ``PYTHONPATH``), interleaved
with this one (A then B, ``--repeats`` times), so both see the same machine load.

Usage (after ``. scripts/bootstrap.sh``)::

    python bench/bench_up.py --thrusters 1 4 8 --rates 50 --seconds 15 --warmup 25 \
        --baseline /tmp/base --repeats 3 --subscriber
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
from collections import defaultdict
from pathlib import Path

from procstat import cpu_seconds
from results_file import Run, add_results_option

# Process part by what its command line runs, first match wins: (text, part, group). The
# command players run in a container too: they must match before the vehicle's container.
PARTS = (
    ("bench_up.py --listen", "external subscriber", "external"),
    ("thruster_fdd_shore.nodes.command_player", "command players", "sim"),
    ("thruster_fdd.nodes.recorder", "recorder", "vehicle"),
    ("thruster_fdd.nodes.health", "health", "vehicle"),
    ("thruster_fdd.nodes.container esc_driver", "vehicle container", "vehicle"),
    ("thruster_fdd.nodes.container", "models", "vehicle"),
    ("thruster_fdd.nodes.esc_driver", "drivers", "vehicle"),
    (" emulate ", "emulators", "sim"),
)


def _descendants(pid: int) -> list[int]:
    children: dict[int, list[int]] = defaultdict(list)
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children[int(fields[1])].append(int(stat.parent.name))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out


def _sample(pid: int) -> tuple[float, float, float, str, str] | None:
    """CPU seconds, RSS and PSS in MB, part and group of process ``pid``."""
    try:
        cpu_s = cpu_seconds(pid)
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        rollup = Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines()
    except OSError:
        return None
    kb = {line.split(":")[0]: int(line.split()[1]) for line in rollup[1:] if ":" in line}
    part, group = next(((p, g) for key, p, g in PARTS if key in cmdline), ("up", "up"))
    return cpu_s, kb.get("Rss", 0) / 1024, kb.get("Pss", 0) / 1024, part, group


def listen(thruster_ids: list[str]) -> None:
    """An external subscriber to every thruster's ``esc/telemetry`` until SIGINT."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from thruster_fdd_msgs.msg import EscTelemetry

    rclpy.init()
    node = rclpy.create_node("bench_listener")
    for tid in thruster_ids:
        node.create_subscription(
            EscTelemetry, f"/thruster/{tid}/esc/telemetry", lambda _: None, qos_profile_sensor_data
        )
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        rclpy.try_shutdown()


def run_once(
    thrusters: int,
    rate: float,
    seconds: float,
    warmup: float,
    source: str | None,
    subscriber: bool = False,
) -> dict[str, tuple[float, float, float, int]]:
    """Run one configuration; returns cores, RSS MB, PSS MB and process count by part and by
    group (keys ``group:<name>``); ``subscriber``: with the external subscriber (a child of
    this process, sampled as its own group)."""
    out_dir = tempfile.mkdtemp(prefix="bench_up_")
    env = dict(os.environ)
    if source:
        env["PYTHONPATH"] = ":".join(
            [
                f"{source}/src/thruster_fdd",
                f"{source}/src/thruster_fdd_shore",
                env.get("PYTHONPATH", ""),
            ]
        )
    proc = subprocess.Popen(
        [sys.executable, "-m", "thruster_fdd_shore.cli", "up", "--thrusters", str(thrusters),
         "--rate", str(rate), "--duration", str(warmup + seconds + 5), "--print-period", "1000",
         "--record-dir", out_dir],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )  # fmt: skip
    ids = [f"t{i}" for i in range(thrusters)]
    listener = (
        subprocess.Popen([sys.executable, __file__, "--listen", *ids], env=env)
        if subscriber
        else None
    )
    pids = [proc.pid, *([listener.pid] if listener else [])]
    time.sleep(warmup)
    first = {p: s for root in pids for p in _descendants(root) if (s := _sample(p))}
    t0 = time.monotonic()
    time.sleep(seconds)
    last = {p: s for root in pids for p in _descendants(root) if (s := _sample(p))}
    wall = time.monotonic() - t0
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=60)
    if listener is not None:
        listener.send_signal(signal.SIGINT)
        listener.wait(timeout=30)
    shutil.rmtree(out_dir, ignore_errors=True)
    totals: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0, 0.0, 0])
    for pid, (cpu_s, rss, pss, part, group) in last.items():
        cores = (cpu_s - first.get(pid, (cpu_s,))[0]) / wall
        for key in (part, f"group:{group}"):
            t = totals[key]
            t[0] += cores
            t[1] += rss
            t[2] += pss
            t[3] += 1
    return {k: (v[0], v[1], v[2], int(v[3])) for k, v in totals.items()}


def report(label: str, thrusters: int, rate: float, totals: dict) -> None:
    """Print one configuration's line."""

    def fmt(key: str) -> str:
        cores, rss, pss, n = totals.get(key, (0.0, 0.0, 0.0, 0))
        return f"{cores:.3f} cores, {rss:.0f} MB [{pss:.0f}] in {n}"

    parts = ", ".join(
        f"{k} {v[0]:.3f}/{v[1]:.0f}" for k, v in sorted(totals.items()) if ":" not in k
    )
    every = [v for k, v in totals.items() if k.startswith("group:")]
    print(
        f"{label:8s} {thrusters} x {rate:g} Hz, load {os.getloadavg()[0]:.1f}: "
        f"vehicle set {fmt('group:vehicle')}; sim harness {fmt('group:sim')}; up {fmt('group:up')}"
        f"; all {sum(v[0] for v in every):.2f} cores, {sum(v[1] for v in every):.0f} MB "
        f"in {sum(v[3] for v in every)} processes ({parts}; cores/MB RSS)",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--thrusters", type=int, nargs="+", default=[1, 4, 8])
    parser.add_argument("--rates", type=float, nargs="+", default=[50.0])
    parser.add_argument("--seconds", type=float, default=15.0, help="measured interval, s")
    parser.add_argument("--warmup", type=float, default=25.0, help="start-up not measured, s")
    parser.add_argument(
        "--baseline", metavar="SRC", help="source tree of the layout to compare with (A/B)"
    )
    parser.add_argument("--repeats", type=int, default=1, help="A/B pairs per configuration")
    parser.add_argument(
        "--subscriber",
        action="store_true",
        help="also run this version with one external subscriber to every telemetry topic",
    )
    parser.add_argument("--listen", nargs="+", metavar="ID", help=argparse.SUPPRESS)
    add_results_option(parser)
    args = parser.parse_args()
    if args.listen:
        listen(args.listen)
        return
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    run = Run("bench_up")
    measured: dict[tuple[str, int, float], list[tuple[float, float, int]]] = defaultdict(list)
    for n in args.thrusters:
        for rate in args.rates:
            for _ in range(args.repeats):
                if args.baseline:
                    totals = run_once(n, rate, args.seconds, args.warmup, args.baseline)
                    report("baseline", n, rate, totals)
                    measured["baseline", n, rate].append(_vehicle(totals))
                totals = run_once(n, rate, args.seconds, args.warmup, None)
                report("this", n, rate, totals)
                measured["this", n, rate].append(_vehicle(totals))
                if args.subscriber:
                    totals = run_once(n, rate, args.seconds, args.warmup, None, subscriber=True)
                    report("this+sub", n, rate, totals)
                    measured["this, one external subscriber", n, rate].append(_vehicle(totals))
    for (label, n, rate), runs in measured.items():
        run.add(
            f"vehicle set CPU, {n} thrusters x {rate:g} Hz ({label})", "cores",
            statistics.median(r[0] for r in runs), runs=len(runs),
            rss_mb=statistics.median(r[1] for r in runs), processes=runs[0][2],
        )  # fmt: skip
    run.write(args.results, baseline=args.baseline)


def _vehicle(totals: dict[str, tuple[float, float, float, int]]) -> tuple[float, float, int]:
    """Cores, RSS MB and process count of the vehicle set."""
    cores, rss, _, n = totals.get("group:vehicle", (0.0, 0.0, 0.0, 0))
    return cores, rss, n


if __name__ == "__main__":
    main()
