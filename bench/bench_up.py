"""Benchmark: CPU and resident memory of the whole `thruster-fdd up` set.

For each (thrusters, rate) pair, runs ``thruster-fdd up`` for ``--seconds`` (simulated
thrusters, recorder on, model nodes when models are exported), samples every process of the
set from /proc after a warm-up, and prints the set's CPU use (cores: CPU seconds per wall second
over the measured interval) and total resident memory, split by process kind.

Usage (after ``. scripts/bootstrap.sh``)::

    python bench/bench_up.py --thrusters 1 4 8 --rates 10 50 --seconds 20
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import tempfile
import time
from collections import defaultdict
from pathlib import Path

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
# Process kinds by what their command line runs (the model container hosts both model stages).
KINDS = {
    "thruster_fdd.nodes.container": "models (container)",
    "emulate": "emulate",
    "thruster_fdd.nodes.esc_driver": "esc_driver",
    "thruster_fdd.nodes.command_player": "command_player",
    "thruster_fdd.nodes.recorder": "recorder",
}


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


def _sample(pid: int) -> tuple[float, float, str] | None:
    """CPU seconds, RSS in MB and the process kind."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        rss_kb = next(
            int(line.split()[1])
            for line in Path(f"/proc/{pid}/status").read_text().splitlines()
            if line.startswith("VmRSS:")
        )
    except (OSError, StopIteration):
        return None
    kind = next((name for key, name in KINDS.items() if key in cmdline), "up (monitor)")
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS, rss_kb / 1024, kind


def run_once(thrusters: int, rate: float, seconds: float, warmup: float) -> None:
    """Run one configuration and print its line."""
    out_dir = tempfile.mkdtemp(prefix="bench_up_")
    proc = subprocess.Popen(
        [
            "thruster-fdd",
            "up",
            "--thrusters",
            str(thrusters),
            "--rate",
            str(rate),
            "--duration",
            str(warmup + seconds + 5),
            "--print-period",
            "1000",
            "--record-dir",
            out_dir,
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    time.sleep(warmup)
    first = {p: s for p in _descendants(proc.pid) if (s := _sample(p))}
    t0 = time.monotonic()
    time.sleep(seconds)
    last = {p: s for p in _descendants(proc.pid) if (s := _sample(p))}
    wall = time.monotonic() - t0
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=60)
    cpu: dict[str, float] = defaultdict(float)
    rss: dict[str, float] = defaultdict(float)
    for pid, (cpu_s, rss_mb, kind) in last.items():
        cpu[kind] += (cpu_s - first.get(pid, (cpu_s, 0.0, kind))[0]) / wall
        rss[kind] += rss_mb
    detail = ", ".join(f"{k} {cpu[k]:.2f}/{rss[k]:.0f}" for k in sorted(cpu))
    print(
        f"{thrusters} thruster(s) at {rate:g} Hz: CPU {sum(cpu.values()):.2f} cores, "
        f"RSS {sum(rss.values()):.0f} MB in {len(last)} processes ({detail}; cores/MB)",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--thrusters", type=int, nargs="+", default=[1, 4, 8])
    parser.add_argument("--rates", type=float, nargs="+", default=[10.0, 50.0])
    parser.add_argument("--seconds", type=float, default=20.0, help="measured interval, s")
    parser.add_argument("--warmup", type=float, default=15.0, help="start-up not measured, s")
    args = parser.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    for n in args.thrusters:
        for rate in args.rates:
            run_once(n, rate, args.seconds, args.warmup)


if __name__ == "__main__":
    main()
