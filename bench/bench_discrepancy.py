"""Benchmark: wall time of one full discrepancy run on a 10-minute trace at 10 Hz.

The measured trace hides ``dead_time`` from the t100 model (``core.sim.cases``): by
default a trace of the preset's own base physics (``make_case``), with ``--mismatch t100`` or
``t200`` one whose base physics differ from the preset's (``make_mismatch_case``, seed
``--seed``). The run is the whole workflow of ``thruster-fdd discrepancy`` (calibration,
selection steps, report files). Target: < 60 s on the 2-core machine.

Usage: ``python bench/bench_discrepancy.py [--hidden dead_time ...] [--mismatch t100]
[--workers 2]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time

from results_file import Run, add_results_option

from thruster_fdd_shore.core.discrepancy.engine import run_workflow
from thruster_fdd_shore.core.discrepancy.report import write_report
from thruster_fdd_shore.core.sim.cases import make_case, make_mismatch_case


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hidden", nargs="*", default=["dead_time"])
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--mismatch", choices=("t100", "t200"), help="base physics differ from this preset"
    )
    add_results_option(parser)
    args = parser.parse_args()
    if args.mismatch:
        case = make_mismatch_case(
            tuple(args.hidden), args.seed, preset=args.mismatch, duration_s=args.duration
        )
    else:
        case = make_case(tuple(args.hidden), args.seed, duration_s=args.duration)
    base = (
        f"base of {args.mismatch} changed: {', '.join(case.switches)}" if args.mismatch else "t100"
    )
    load = os.getloadavg()[0]
    run = Run("bench_discrepancy")
    start = time.perf_counter()
    cpu0 = _cpu_s()
    result, data = run_workflow(case.trace, case.start, workers=args.workers, progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        write_report(result, data, f"{tmp}/report")
    wall = time.perf_counter() - start
    cpu = _cpu_s() - cpu0
    print(
        f"{len(case.trace)} samples ({args.duration:.0f} s at 10 Hz), {base}; hidden "
        f"{', '.join(args.hidden) or 'nothing'}: named {', '.join(result.added) or 'nothing'} "
        f"in {wall:.1f} s wall, {cpu:.1f} s CPU ({args.workers} worker(s); load "
        f"average {load:.2f} at start, {os.getloadavg()[0]:.2f} at end; target < 60 s wall)"
    )
    what = f"one discrepancy run, {args.duration:g} s at 10 Hz, {base}, {args.workers} workers"
    run.add(what, "s wall", wall, cpu_s=cpu)
    run.write(args.results, hidden=args.hidden, named=list(result.added))


def _cpu_s() -> float:
    """User + system CPU time of this process and its finished children (workers), s."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


if __name__ == "__main__":
    main()
