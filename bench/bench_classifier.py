"""Benchmark of the online diagnosis stream: per-decision and per-sample latency.

Usage: ``python bench/bench_classifier.py [--models models] [--duration 1200] [--runs 3]``.
Feeds simulated t100 mission telemetry (10 Hz, the nominal model's rate) through
``ResidualStream`` and ``DiagnosisStream`` as the nodes do, and times every
``DiagnosisStream.push``: the pushes that return a Decision (window features + exported MLP +
calibration + distance, once per hop) and the others (window bookkeeping). Prints median and p99
in µs over all runs.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from results_file import Run, add_results_option

from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.diagnosis.stream import DiagnosisStream
from thruster_fdd.core.nominal.residuals import ResidualStream
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd_shore.core.diagnosis.offline import check_pair
from thruster_fdd_shore.core.sim.scenario import run_scenario


def percentiles_us(samples: list[float]) -> tuple[float, float]:
    """Median and 99th percentile of durations in s, as µs."""
    arr = np.asarray(samples) * 1e6
    return float(np.median(arr)), float(np.percentile(arr, 99))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, default=Path("models"))
    parser.add_argument("--duration", type=float, default=1200.0, help="s of telemetry per run")
    parser.add_argument("--runs", type=int, default=3)
    add_results_option(parser)
    args = parser.parse_args()
    torch.set_num_threads(1)
    run = Run("bench_classifier")
    nominal = NominalModel.load(args.models / "nominal")
    classifier = ClassifierModel.load(args.models / "classifier")
    check_pair(nominal, classifier, args.models / "classifier")
    decide, other = [], []
    for k in range(args.runs):
        trace = run_scenario(
            "t100", "biofouling", signal="mission", duration_s=args.duration, seed=500 + k
        )
        residuals = ResidualStream(nominal)
        residuals.reset()
        stream = DiagnosisStream(classifier)
        columns = (trace.t, trace.command, trace.voltage, trace.rpm, trace.current)
        for t, c, v, r, i in zip(*(a.tolist() for a in columns), strict=True):
            s = residuals.push(t, c, v, r, i)
            if s is None:
                continue
            start = time.perf_counter()
            d = stream.push(t, c, v, r, i, s.residual_rpm, s.residual_current_a, s.valid)
            elapsed = time.perf_counter() - start
            (decide if d is not None else other).append(elapsed)
    med, p99 = percentiles_us(decide)
    run.add("DiagnosisStream.push returning a decision", "us", med, p99=p99, count=len(decide))
    print(f"classifier {classifier.model_id}, window {classifier.window_s:g} s, hop 1 s")
    print(
        f"push returning a Decision: median {med:.0f} us, p99 {p99:.0f} us "
        f"({len(decide)} decisions)"
    )
    med, p99 = percentiles_us(other)
    run.add("DiagnosisStream.push without a decision", "us", med, p99=p99, count=len(other))
    print(
        f"push without a Decision:   median {med:.1f} us, p99 {p99:.1f} us ({len(other)} samples)"
    )
    run.write(args.results, classifier=classifier.model_id, runs=args.runs)


if __name__ == "__main__":
    main()
