"""Benchmark of the nominal NARX: training time, per-sample online inference, peak RSS.

Usage: ``python bench/bench_nominal.py [--model models/nominal] [--samples 2000] [--steps 20000]``.
Targets: training on 2000 samples < 60 s (2-core CPU, one torch thread); online step median
<= 100 us and p99 <= 1 ms. Prints the step time of ``NominalModel.step`` (numpy evaluation of the
exported program's own weights) and, for comparison, of calling the exported program itself per
sample (``ExportedProgram.module()`` under ``torch.inference_mode``).
"""

from __future__ import annotations

import argparse
import resource
import time
from dataclasses import replace

import numpy as np
import torch
from results_file import Run, add_results_option

from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd_shore.core.nominal.evaluation import ProtocolConfig, protocol_data
from thruster_fdd_shore.core.nominal.training import DEFAULT_SPECS, default_config, train_model


def percentiles_us(samples: list[float]) -> tuple[float, float]:
    """Median and 99th percentile of durations in s, as µs."""
    arr = np.asarray(samples) * 1e6
    return float(np.median(arr)), float(np.percentile(arr, 99))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="models/nominal")
    parser.add_argument("--samples", type=int, default=2000, help="training samples")
    parser.add_argument("--steps", type=int, default=20000, help="online steps timed")
    add_results_option(parser)
    args = parser.parse_args()
    torch.set_num_threads(1)
    run = Run("bench_nominal")

    cfg = replace(ProtocolConfig(), train_samples=args.samples)
    train, tests = protocol_data(cfg, 0)
    for mode, spec in DEFAULT_SPECS.items():
        start = time.perf_counter()
        train_model(spec, [train], default_config(mode))
        train_s = time.perf_counter() - start
        print(f"training ({spec.architecture}, {mode}, {args.samples} samples): {train_s:.1f} s")
        run.add(f"training, {mode}, {args.samples} samples, 1 thread", "s", train_s)

    model = NominalModel.load(args.model)
    test = tests[0.04]
    n = len(test.u)
    rows = [(*test.u[i % n], *test.y[i % n]) for i in range(args.steps)]
    for mode in ("parallel", "series-parallel"):
        model.mode = mode
        model.reset()
        times = []
        for row in rows:
            t0 = time.perf_counter()
            model.step(*row)
            times.append(time.perf_counter() - t0)
        med, p99 = percentiles_us(times[model.warmup_samples :])
        print(f"NominalModel.step ({mode}): median {med:.1f} us, p99 {p99:.1f} us")
        run.add(f"NominalModel.step, {mode}", "us", med, p99=p99)

    module = torch.export.load(f"{args.model}/model.pt2").module()
    nu, ny = model.card.lookbacks["input"], model.card.lookbacks["output"]
    u = torch.zeros(1, nu, 2)
    y = torch.zeros(1, ny, 2)
    times = []
    with torch.inference_mode():
        for _ in range(min(args.steps, 5000)):
            t0 = time.perf_counter()
            module(u, y)
            times.append(time.perf_counter() - t0)
    med, p99 = percentiles_us(times[100:])
    print(f"exported program call per sample (torch): median {med:.1f} us, p99 {p99:.1f} us")
    run.add("exported program call per sample (torch)", "us", med, p99=p99)
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS: {rss_mb:.0f} MB")
    run.add("peak RSS of the process", "MB", rss_mb)
    run.write(args.results)


if __name__ == "__main__":
    main()
