"""Many-seeds study of the discrepancy workflow on traces with hidden effects.

For every effect of the vocabulary (and effect pairs, and null traces with nothing hidden) and
every seed, simulates a noisy "measured" t100 trace with the effect hidden from the model
(``core.discrepancy.cases``), runs the workflow, and prints a Markdown table: detection rate,
median / worst parameter error, gap shrink (held-out score), false-positive rate.

Each case uses the command signal that excites its effect (``discrepancy_cases.EXCITING``:
fast large steps for ``slew_rate_limit`` and ``current_limit``, low-speed ramps through zero for
the friction terms, ``multilevel`` otherwise); null traces cycle through all case signals.
Cases run in ``--workers`` processes, one run per process.

Usage::

    python scripts/discrepancy_study.py [--seeds 5] [--duration 120] [--workers 2] \
        [--first-seed 100] [--cases current_limit dead_time+current_limit null] \
        [--json runs.jsonl]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from scipy.stats import beta
from tqdm import tqdm

from thruster_fdd.core.discrepancy.cases import PLAUSIBLE, SIGNALS, make_case
from thruster_fdd.core.discrepancy.measure import Measured, simulate_model
from thruster_fdd.core.discrepancy.search import run_workflow
from thruster_fdd.core.sim.config import SimConfig
from thruster_fdd.core.traces.data import Trace

PAIRS = (
    ("dead_time", "current_limit"),
    ("deadband", "esc_lag"),
    ("coulomb_friction", "voltage_sag"),
)


def _model_error(config: SimConfig, clean: Trace, data: Measured) -> float:
    """Held-out mean squared error of ``config``'s free run against the unit's noise-free
    response, rpm and current (the signals of report.json's gap), in noise-variance units.

    The bus voltage is left out: the model's comes from the measured one through the supply
    reconstruction, not from the model.
    """
    sim = simulate_model(config, data)
    return float(
        np.mean(
            [
                np.mean((sim[c] - getattr(clean, c))[data.held] ** 2) / data.sigma[c] ** 2
                for c in ("rpm", "current")
            ]
        )
    )


def one(job: tuple[tuple[str, ...], int, float]) -> dict:
    """Run one case; return what was hidden, what was named, errors and gap shrink."""
    hidden, seed, duration = job
    signal = None if hidden else SIGNALS[seed % len(SIGNALS)]
    case = make_case(hidden, seed, duration_s=duration, signal=signal)
    t0 = time.perf_counter()
    result, data = run_workflow(case.trace, case.start, workers=1, progress=False)
    rep = result.report()
    model_error = [_model_error(f.config, case.clean, data) for f in (result.start, result.final)]
    errors = {}
    for name, params in case.hidden.items():
        found = next((m for m in rep["missing_effects"] if m["name"] == name), None)
        if found is not None:
            errors[name] = max(abs(found["params"][p] / v - 1.0) for p, v in params.items())
    return {
        "hidden": list(hidden),
        "seed": seed,
        "signal": case.signal,
        "named": list(result.added),
        "verdict": result.verdict,
        "param_error": errors,
        "score_before": result.start.gap.score,
        "score_after": result.final.gap.score,
        "model_error_before": model_error[0],
        "model_error_after": model_error[1],
        "gap_before": rep["gap_before"],
        "gap_after": rep["gap_after"],
        "wall_s": time.perf_counter() - t0,
    }


def upper_bound(failures: int, runs: int, confidence: float = 0.95) -> float:
    """One-sided Clopper-Pearson upper confidence bound of a rate seen ``failures``/``runs``."""
    if failures >= runs:
        return 1.0
    return float(beta.ppf(confidence, failures + 1, runs - failures))


def table(rows: list[dict]) -> str:
    """Markdown table per hidden set.

    "shrink >= 1/2": runs whose held-out score at least halved. "excess shrink >= 1/2": runs
    whose excess over noise (score - 1, the part a model can explain) at least halved; near the
    noise floor (friction) the score itself cannot halve even when the right effect is named.
    "model error": the held-out mean squared error of rpm and current in noise-variance units,
    but against the unit's noise-free response (``Case.clean``) instead of the noisy
    measurement, so it has no noise floor; "halved": runs where it at least halved.
    """
    out = [
        "| hidden | runs | detected (exactly) | param error median / max | within 20 % "
        "| score before -> after (median) | shrink >= 1/2 | excess shrink >= 1/2 "
        "| model error before -> after (median) | model error halved |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[str, list[dict]] = {}
    for r in rows:
        groups.setdefault("+".join(r["hidden"]) or "(nothing: null)", []).append(r)
    for key, rs in groups.items():
        exact = sum(sorted(r["named"]) == sorted(r["hidden"]) for r in rs)
        errs = [e for r in rs for e in r["param_error"].values()]
        err = f"{100 * statistics.median(errs):.1f} % / {100 * max(errs):.1f} %" if errs else "-"
        within = f"{sum(e <= 0.2 for e in errs)}/{len(errs)}" if errs else "-"
        sb = statistics.median(r["score_before"] for r in rs)
        sa = statistics.median(r["score_after"] for r in rs)
        shrink = excess = model = model_halved = "-"
        if rs[0]["hidden"]:
            shrink = f"{sum(r['score_after'] <= 0.5 * r['score_before'] for r in rs)}/{len(rs)}"
            halved = sum(r["score_after"] - 1.0 <= 0.5 * (r["score_before"] - 1.0) for r in rs)
            excess = f"{halved}/{len(rs)}"
        if rs[0]["hidden"] and "model_error_before" in rs[0]:  # absent in older JSON files
            mb = statistics.median(r["model_error_before"] for r in rs)
            ma = statistics.median(r["model_error_after"] for r in rs)
            model = f"{mb:.2f} -> {ma:.3f}"
            there = sum(r["model_error_after"] <= 0.5 * r["model_error_before"] for r in rs)
            model_halved = f"{there}/{len(rs)}"
        out.append(
            f"| {key} | {len(rs)} | {exact}/{len(rs)} | {err} | {within} | {sb:.1f} -> {sa:.2f} "
            f"| {shrink} | {excess} | {model} | {model_halved} |"
        )
    nulls = [r for r in rows if not r["hidden"]]
    if nulls:
        fp = sum(bool(r["named"]) for r in nulls)
        out.append("")
        out.append(
            f"False-positive rate (null traces naming any effect): {fp}/{len(nulls)} "
            f"(one-sided 95 % upper bound {100 * upper_bound(fp, len(nulls)):.1f} %)."
        )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5, help="seeds per case (default 5)")
    parser.add_argument(
        "--first-seed",
        type=int,
        default=100,
        help="first seed (default 100; null traces use first-seed + 0 .. 2 x seeds - 1)",
    )
    parser.add_argument(
        "--duration", type=float, default=120.0, help="trace length, s (default 120)"
    )
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--json", type=Path, help="also write every run as JSON lines")
    parser.add_argument("--table", type=Path, help="only print the table of such a JSON file")
    parser.add_argument(
        "--cases",
        nargs="+",
        metavar="CASE",
        help="run only these cases: an effect, a pair as EFFECT+EFFECT (of the study's pairs) "
        "or 'null' (default: every effect, every pair and two null traces per seed)",
    )
    args = parser.parse_args(argv)
    if args.table:
        print(table([json.loads(line) for line in args.table.read_text().splitlines()]))
        return 0
    wanted = [*[(name,) for name in PLAUSIBLE], *PAIRS, ()]
    if args.cases:
        by_name = {"+".join(h) or "null": h for h in wanted}
        unknown = [c for c in args.cases if c not in by_name]
        if unknown:
            parser.error(f"unknown case(s) {unknown}; expected some of {', '.join(by_name)}")
        wanted = [by_name[c] for c in args.cases]
    cases = []
    for s in range(args.seeds):  # seed-major: a study stopped early still covers every case
        cases += [(hidden, s) for hidden in wanted if hidden]
        if () in wanted:
            cases += [((), 2 * s), ((), 2 * s + 1)]
    jobs = [(hidden, args.first_seed + seed, args.duration) for hidden, seed in cases]
    rows = []
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.workers, mp_context=get_context("fork")) as pool:
        for row in tqdm(pool.map(one, jobs), total=len(jobs), desc="study", unit="run"):
            rows.append(row)
            if args.json:
                with args.json.open("a") as f:
                    f.write(json.dumps(row) + "\n")
    print(table(rows))
    print(
        f"\n{len(rows)} runs, {args.duration:.0f} s traces, {time.perf_counter() - t0:.0f} s wall "
        f"in {args.workers} processes (load average at start {load:.2f})."
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
