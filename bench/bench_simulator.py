"""Benchmark: simulated seconds per wall-clock second of one thruster (median of repeats).

Usage: ``python bench/bench_simulator.py [--preset t100] [--repeats 5] [--duration 3600]``.
Target: >= 1000x real time at 10 Hz.
"""

from __future__ import annotations

import argparse
import statistics
import time

from results_file import Run, add_results_option

from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import simulate
from thruster_fdd_shore.core.sim.signals import make_signal


def speed(preset: str, rate_hz: float, duration_s: float, repeats: int) -> float:
    """Median simulated s per wall s of ``simulate`` on the mission signal."""
    config = load_config(preset)
    t, u = make_signal("mission", duration_s, rate_hz, seed=0)
    ratios = []
    for seed in range(repeats):
        start = time.perf_counter()
        simulate(config, t, u, "broken_blade_1", seed=seed)
        ratios.append(duration_s / (time.perf_counter() - start))
    return statistics.median(ratios)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="t100")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--duration", type=float, default=3600.0, help="simulated s per run")
    add_results_option(parser)
    args = parser.parse_args()
    run = Run("bench_simulator")
    for rate in (10.0, 100.0):
        ratio = speed(args.preset, rate, args.duration, args.repeats)
        print(f"{args.preset} at {rate:g} Hz: {ratio:.0f} simulated s per wall s (median of "
              f"{args.repeats}, {args.duration:g} s runs)")  # fmt: skip
        run.add(f"simulated s per wall s, {args.preset} at {rate:g} Hz, mission signal", "x",
                ratio, runs=args.repeats)  # fmt: skip
    run.write(args.results)


if __name__ == "__main__":
    main()
