"""Many-seeds study of the discrepancy workflow on traces with hidden effects, in three kinds of
family.

- ``exact``: t100 traces whose base physics are the start preset's exactly (plus unit spread);
  every effect of the vocabulary hidden in turn, three pairs, null traces with nothing hidden
  (``core.sim.cases.make_case``). Each case runs on the signal that excites its effect
  (``cases.EXCITING``); null traces cycle through all case signals. Default 60 s traces.
- ``t100`` / ``t200``: mismatch traces (``cases.make_mismatch_case``): the measured thruster
  differs from the start preset by a random combination of structural switches outside the
  effect vocabulary (``cases.MISMATCH_SWITCHES``), the start keeps only ``esc_lag``; single
  and paired hidden effects, null traces, and starts holding an effect the thruster lacks
  (``superfluous: NAME``). The ``mixed`` signal; default 600 s traces.
- ``throttle_curve``, ``rpm_filter``, ``command_hysteresis``, ``reverse_limit``,
  ``command_steps``, ``rpm_delay``, ``current_filter`` (``cases.OUTSIDE``): t100 thrusters with
  a structure neither the simulator nor the vocabulary has (``cases.make_outside_case``), null
  traces and a hidden deadband, dead time or sag. ``multilevel`` commands; default 240 s
  traces.

Per case and seed it runs the workflow and records what was hidden, named (missing and
superfluous), the parameter errors and the gap before and after; it prints one Markdown table
per family: exact naming, parameter error, gap shrink, model error (against the unit's
noise-free response), and the false-positive rate of the null traces with a one-sided 95 %
upper bound. Runs go to ``--workers`` processes, one run each. ``--json`` keeps each run's
row, with how the search got there: the moves within the score's uncertainty of each choice,
the base changes made and whether a structured rest was left. ``--out DIR``
writes the tables as ``DIR/table.md`` and every run as ``DIR/runs.jsonl`` (with ``--table``:
the table of that file only).

Usage::

    python scripts/discrepancy_study.py [--family exact t100 t200 ...] [--seeds 5] \
        [--first-seed 100] [--duration S] [--workers 2] [--cases null deadband ...] \
        [--json runs.jsonl] [--out DIR]
    python scripts/discrepancy_study.py --table runs.jsonl [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from scipy.stats import beta
from tqdm import tqdm

from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.discrepancy.engine import run_workflow
from thruster_fdd_shore.core.discrepancy.measure import CHANNELS, Measured, simulate_model
from thruster_fdd_shore.core.discrepancy.report import (
    FRICTION_UNITS,
    friction_currents,
    gaps_of,
    report_json,
    simulations,
)
from thruster_fdd_shore.core.sim.cases import (
    MISMATCH_DURATION_S,
    MISMATCH_HIDDEN,
    MISMATCH_PAIRS,
    OUTSIDE,
    PLAUSIBLE,
    SIGNALS,
    SUPERFLUOUS,
    Case,
    make_case,
    make_mismatch_case,
    make_outside_case,
)
from thruster_fdd_shore.core.sim.config import Measurement, SimConfig, without_effects
from thruster_fdd_shore.core.sim.physics import simulate

PAIRS = (
    ("dead_time", "current_limit"),
    ("deadband", "esc_lag"),
    ("coulomb_friction", "voltage_sag"),
)
"""Hidden pairs of the exact-base family."""


FAMILIES = ("exact", "t100", "t200", *OUTSIDE)
"""``exact``: base physics of the start preset (t100); ``t100`` / ``t200``: mismatch cases
starting from that preset; ``throttle_curve`` / ``rpm_filter`` / ``command_hysteresis``: a
structure neither the simulator nor the vocabulary has (``cases.make_outside_case``)."""

OUTSIDE_HIDDEN = ("deadband", "dead_time", "voltage_sag")
"""Effects hidden beside a structure outside the vocabulary."""

OUTSIDE_DURATION_S = 240.0


EXACT_DURATION_S = 60.0


def _noise_units(
    diff: Callable[[str], np.ndarray], sigma: dict[str, float], channels: Sequence[str]
) -> float:
    """Mean over ``channels`` of the mean squared ``diff(channel)``, each in units of that
    channel's noise variance (``sigma``, the measurement's noise estimate)."""
    return float(np.mean([np.mean(diff(c) ** 2) / sigma[c] ** 2 for c in channels]))


def _model_error(config: SimConfig, clean: Trace, data: Measured) -> float:
    """Held-out mean squared error of ``config``'s free run against the unit's noise-free
    response, rpm and current (the signals of report.json's gap), in noise-variance units.

    The bus voltage is left out: the model's comes from the measured one through the supply
    reconstruction, not from the model.
    """
    sim = simulate_model(config, data)
    return _noise_units(
        lambda c: (sim[c] - getattr(clean, c))[data.held], data.sigma, ("rpm", "current")
    )


def _visibility(case: Case, data: Measured, seed: int) -> dict[str, dict[str, float]]:
    """How far each hidden effect moves the unit's noise-free response: the mean squared
    difference of rpm, current and bus voltage (the channels of the held-out score) with against
    without it, in noise-variance units, over the whole trace (``all``), the fit samples
    (``fit``) and the held-out samples (``held``). Under about 1 no method can name it from
    this trace (a current limit the trace never reaches): the case, not the workflow, is at
    fault; under 1 on the fit or the held-out samples alone, the calibration cannot fit it or
    the held-out score cannot show it (a current limit reached only in held-out blocks). Beside
    a structure outside the vocabulary both responses go through it."""
    out = {}
    for name in case.hidden:
        bare = replace(without_effects(case.unit, (name,)), spread=0.0, measurement=Measurement())
        t, u = case.clean.t, case.clean.command
        sim = (
            case.structure.respond(bare, t, u, seed)
            if case.structure
            else simulate(bare, t, u, seed=seed)
        )
        diff = {c: getattr(sim, c) - getattr(case.clean, c) for c in CHANNELS}
        out[name] = {
            part: _noise_units(lambda c, d=diff, m=mask: d[c][m], data.sigma, CHANNELS)
            for part, mask in (("all", slice(None)), ("fit", data.fit), ("held", data.held))
        }
    return out


def _visibility_columns(seen: dict[str, dict[str, float]]) -> dict[str, dict]:
    """A run's ``visibility`` (whole trace, per hidden effect, as before) and
    ``visibility_split`` (effect -> [fit, held-out]) columns."""
    return {
        "visibility": {name: v["all"] for name, v in seen.items()},
        "visibility_split": {name: [v["fit"], v["held"]] for name, v in seen.items()},
    }


def make_job_case(family: str, hidden: tuple[str, ...], superfluous: tuple[str, ...],
                  seed: int, duration: float) -> Case:  # fmt: skip
    """The case of one study run."""
    if family == "exact":
        signal = None if hidden else SIGNALS[seed % len(SIGNALS)]
        return make_case(hidden, seed, duration_s=duration, signal=signal)
    if family in OUTSIDE:
        return make_outside_case(family, hidden, seed, duration_s=duration)
    return make_mismatch_case(
        hidden, seed, preset=family, superfluous=superfluous, duration_s=duration
    )


def one(job: tuple[str, tuple[str, ...], tuple[str, ...], int, float]) -> dict:
    """Run one case; return what was hidden, what was named, errors and gap shrink."""
    family, hidden, superfluous, seed, duration = job
    case = make_job_case(family, hidden, superfluous, seed, duration)
    t0 = time.perf_counter()
    result, data = run_workflow(case.trace, case.start, workers=1, progress=False)
    sims = simulations(result, data)
    gaps = gaps_of(sims, data)
    rep = report_json(result, data, sims, gaps)
    model_error = [_model_error(f.config, case.clean, data) for f in (result.start, result.final)]
    errors = {}
    for name, params in case.hidden.items():
        found = next((m for m in rep["missing_effects"] if m["name"] == name), None)
        if found is not None:
            errors[name] = max(abs(found["params"][p] / v - 1.0) for p, v in params.items())
    # With the drive losses free, k_e trades with a friction torque along a valley of equal fit
    # (docs/discrepancy.md): only the friction current, torque / k_e, is pinned by the data.
    fitted, unit = friction_currents(result.final.config), friction_currents(case.unit)
    friction_current = {n: abs(fitted[n] / unit[n] - 1.0) for n in fitted if n in errors}
    return {
        "family": family,
        "hidden": list(hidden),
        "superfluous": list(case.superfluous),
        "switches": case.switches,
        "seed": seed,
        "signal": case.signal,
        "named": list(result.added),
        "named_superfluous": [m["name"] for m in rep.get("superfluous_effects", [])],
        "verdict": result.verdict,
        "param_error": errors,
        "friction_current_error": friction_current,
        "score_before": gaps["before"]["score"],
        "score_after": gaps["after"]["score"],
        "model_error_before": model_error[0],
        "model_error_after": model_error[1],
        "gap_before": rep["gap_before"],
        "gap_after": rep["gap_after"],
        "wall_s": time.perf_counter() - t0,
        **_visibility_columns(_visibility(case, data, seed)),
        "rivals": [
            [a["taken"], name] for a in rep["alternatives"] for name in a["within_uncertainty"]
        ],
        "base_changes": [c["change"] for c in rep["base_changes"]],
        "structured_rest": rep["rest"]["structured"],
    }


def _undecided(row: dict) -> bool:
    """Whether a hidden effect the run did not name was a rival of what a round took."""
    unnamed = set(row["hidden"]) - set(row["named"])
    return any(rival.removeprefix("add ") in unnamed for _taken, rival in row.get("rivals", []))


def upper_bound(failures: int, runs: int, confidence: float = 0.95) -> float:
    """One-sided Clopper-Pearson upper confidence bound of a rate seen ``failures``/``runs``."""
    if failures >= runs:
        return 1.0
    return float(beta.ppf(confidence, failures + 1, runs - failures))


def exact(row: dict) -> bool:
    """Named exactly what was hidden and what was superfluous, nothing else."""
    return sorted(row["named"]) == sorted(row["hidden"]) and sorted(
        row.get("named_superfluous", [])
    ) == sorted(row.get("superfluous", []))


def _key(row: dict) -> str:
    if row.get("superfluous"):
        return "superfluous: " + "+".join(row["superfluous"])
    return "+".join(row["hidden"]) or "(nothing: null)"


def _summary(rows: list[dict]) -> list[str]:
    """Totals of one family: singles, pairs, nulls (false positives), superfluous."""
    out = []
    singles = [r for r in rows if len(r["hidden"]) == 1 and not r.get("superfluous")]
    pairs = [r for r in rows if len(r["hidden"]) == 2]
    nulls = [r for r in rows if not r["hidden"] and not r.get("superfluous")]
    extra = [r for r in rows if r.get("superfluous")]
    if singles or pairs:
        both = singles + pairs
        errs = [e for r in both for e in r["param_error"].values()]
        halved = sum(r["model_error_after"] <= 0.5 * r["model_error_before"] for r in both)
        out.append(
            f"Named exactly: singles {sum(map(exact, singles))}/{len(singles)}, pairs "
            f"{sum(map(exact, pairs))}/{len(pairs)} (together "
            f"{100 * sum(map(exact, both)) / len(both):.0f} %); parameters within 20 %: "
            f"{sum(e <= 0.2 for e in errs)}/{len(errs)}; model error halved {halved}/{len(both)}."
        )
        seen = [v for r in both for v in r.get("visibility", {}).values()]
        if seen:
            faint = [r for r in both if any(v < 1.0 for v in r.get("visibility", {}).values())]
            out.append(
                f"Visibility of the hidden effects (noise-free response with against without "
                f"each, mean square in noise variances): median {statistics.median(seen):.1f}, "
                f"least {min(seen):.2f}; runs with one under 1: {len(faint)}, named exactly "
                f"{sum(map(exact, faint))}."
            )
        split = [r for r in both if r.get("visibility_split")]
        if split:
            hidden_part = [
                r for r in split if any(min(v) < 1.0 for v in r["visibility_split"].values())
            ]
            out.append(
                f"Runs with a hidden effect under 1 on the fit or the held-out samples alone (the "
                f"calibration cannot fit it or the held-out score cannot show it): "
                f"{len(hidden_part)}/{len(split)}, named exactly {sum(map(exact, hidden_part))}."
            )
        misses = [r for r in both if not exact(r)]
        undecided = [r for r in misses if _undecided(r)]
        out.append(
            f"Misses where a hidden effect the search did not name was within the score's "
            f"uncertainty of what a step took (report.md: choices the data do not decide): "
            f"{len(undecided)}/{len(misses)}."
        )
        cur = [e for r in both for e in r.get("friction_current_error", {}).values()]
        torque = [e for r in both for n, e in r["param_error"].items() if n in FRICTION_UNITS]
        if cur:
            out.append(
                f"Friction torques within 20 %: {sum(e <= 0.2 for e in torque)}/{len(torque)}; "
                f"as friction currents (torque / k_e): {sum(e <= 0.2 for e in cur)}/{len(cur)} "
                f"(median error {100 * statistics.median(torque):.1f} % -> "
                f"{100 * statistics.median(cur):.1f} %)."
            )
    if nulls:
        fp = sum(bool(r["named"] or r.get("named_superfluous")) for r in nulls)
        out.append(
            f"False-positive rate (null traces naming anything): {fp}/{len(nulls)} = "
            f"{100 * fp / len(nulls):.1f} % (one-sided 95 % upper bound "
            f"{100 * upper_bound(fp, len(nulls)):.1f} %); verdict unexplained "
            f"{sum(r['verdict'] == 'unexplained' for r in nulls)}/{len(nulls)}."
        )
    if any("structured_rest" in r for r in rows):
        rest = sum(bool(r.get("structured_rest")) for r in rows)
        out.append(f"Runs leaving a structured rest: {rest}/{len(rows)}.")
    if extra:
        found = sum(sorted(r.get("named_superfluous", [])) == r["superfluous"] for r in extra)
        shrank = sum(r["score_after"] < r["score_before"] for r in extra)
        out.append(
            f"Superfluous effects reported: {found}/{len(extra)} (exactly: "
            f"{sum(map(exact, extra))}); held-out score lower after: {shrank}/{len(extra)}."
        )
    return out


def table(rows: list[dict]) -> str:
    """Markdown table per family and case.

    "named exactly": the named missing effects equal the hidden ones and the named superfluous
    effects the superfluous ones. "shrink >= 1/2": runs whose held-out score at least halved.
    "excess shrink >= 1/2": runs whose excess over noise (score - 1) at least halved.
    "model error": the held-out mean squared error of rpm and current in noise-variance units,
    against the unit's noise-free response (``Case.clean``), so it has no noise floor;
    "halved": runs where it at least halved.
    """
    out = []
    by_family: dict[str, list[dict]] = {}
    for r in rows:
        by_family.setdefault(r.get("family", "exact"), []).append(r)
    for family, frows in by_family.items():
        out += [
            f"**{family}**",
            "",
            "| case | runs | named exactly | param error median / max | within 20 % "
            "| score before -> after (median) | shrink >= 1/2 | excess shrink >= 1/2 "
            "| model error before -> after (median) | model error halved |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        groups: dict[str, list[dict]] = {}
        for r in frows:
            groups.setdefault(_key(r), []).append(r)
        for key, rs in groups.items():
            errs = [e for r in rs for e in r["param_error"].values()]
            err = (
                f"{100 * statistics.median(errs):.1f} % / {100 * max(errs):.1f} %" if errs else "-"
            )
            within = f"{sum(e <= 0.2 for e in errs)}/{len(errs)}" if errs else "-"
            sb = statistics.median(r["score_before"] for r in rs)
            sa = statistics.median(r["score_after"] for r in rs)
            shrink = excess = model = model_halved = "-"
            if rs[0]["hidden"] or rs[0].get("superfluous"):
                shrink = f"{sum(r['score_after'] <= 0.5 * r['score_before'] for r in rs)}/{len(rs)}"
                halved = sum(r["score_after"] - 1.0 <= 0.5 * (r["score_before"] - 1.0) for r in rs)
                excess = f"{halved}/{len(rs)}"
                mb = statistics.median(r["model_error_before"] for r in rs)
                ma = statistics.median(r["model_error_after"] for r in rs)
                model = f"{mb:.2f} -> {ma:.3f}"
                there = sum(r["model_error_after"] <= 0.5 * r["model_error_before"] for r in rs)
                model_halved = f"{there}/{len(rs)}"
            out.append(
                f"| {key} | {len(rs)} | {sum(map(exact, rs))}/{len(rs)} | {err} | {within} "
                f"| {sb:.1f} -> {sa:.2f} | {shrink} | {excess} | {model} | {model_halved} |"
            )
        out += ["", *_summary(frows), ""]
    return "\n".join(out)


def _wanted(family: str) -> list[tuple[tuple[str, ...], tuple[str, ...]]]:
    """(hidden, superfluous) of every case kind of ``family``; () () is the null trace."""
    if family in OUTSIDE:
        return [*(((name,), ()) for name in OUTSIDE_HIDDEN), ((), ())]
    if family == "exact":
        kinds = [((name,), ()) for name in PLAUSIBLE] + [(p, ()) for p in PAIRS]
    else:
        kinds = [((name,), ()) for name in MISMATCH_HIDDEN] + [(p, ()) for p in MISMATCH_PAIRS]
        kinds += [((), (name,)) for name in SUPERFLUOUS]
    return [*kinds, ((), ())]


def _case_name(hidden: tuple[str, ...], superfluous: tuple[str, ...]) -> str:
    if superfluous:
        return "superfluous:" + "+".join(superfluous)
    return "+".join(hidden) or "null"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--family", nargs="+", choices=FAMILIES, default=list(FAMILIES),
                        help="case families (default: all)")  # fmt: skip
    parser.add_argument("--seeds", type=int, default=5, help="seeds per case (default 5)")
    parser.add_argument(
        "--first-seed",
        type=int,
        default=100,
        help="first seed (default 100; null traces use first-seed + 0 .. 2 x seeds - 1)",
    )
    parser.add_argument("--duration", type=float,
                        help=f"trace length, s (default {EXACT_DURATION_S:g} for exact, "
                        f"{MISMATCH_DURATION_S:g} for the mismatch families)")  # fmt: skip
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--json", type=Path, help="also append every run as a JSON line")
    parser.add_argument("--table", type=Path, help="only print the table of such a JSON file")
    parser.add_argument("--out", type=Path,
                        help="write table.md and runs.jsonl into this folder")  # fmt: skip
    parser.add_argument(
        "--cases",
        nargs="+",
        metavar="CASE",
        help="run only these cases: an effect, a pair as EFFECT+EFFECT (of the family's "
        "pairs), 'null', or 'superfluous:EFFECT' (mismatch families)",
    )
    args = parser.parse_args(argv)
    if args.table:
        rows = [json.loads(line) for line in args.table.read_text().splitlines()]
        print(table(rows))
        _write_out(args.out, rows, table(rows))
        return 0
    jobs = []
    for family in args.family:
        wanted = _wanted(family)
        if args.cases:
            by_name = {_case_name(*w): w for w in wanted}
            wanted = [by_name[c] for c in args.cases if c in by_name]
            if not wanted:
                parser.error(f"no case of {args.cases} in family {family}; known: {list(by_name)}")
        default = {"exact": EXACT_DURATION_S, **dict.fromkeys(OUTSIDE, OUTSIDE_DURATION_S)}
        duration = args.duration or default.get(family, MISMATCH_DURATION_S)
        for s in range(args.seeds):  # seed-major: a study stopped early still covers every case
            for hidden, superfluous in wanted:
                if hidden or superfluous:
                    jobs.append((family, hidden, superfluous, args.first_seed + s, duration))
                else:
                    for k in (2 * s, 2 * s + 1):
                        jobs.append((family, (), (), args.first_seed + k, duration))
    rows = []
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.workers, mp_context=get_context("fork")) as pool:
        for row in tqdm(pool.map(one, jobs), total=len(jobs), desc="study", unit="run"):
            rows.append(row)
            if args.json:
                with args.json.open("a") as f:
                    f.write(json.dumps(row) + "\n")
    text = table(rows)
    print(text)
    footer = (
        f"{len(rows)} runs, {time.perf_counter() - t0:.0f} s wall in {args.workers} processes "
        f"(load average at start {load:.2f})."
    )
    print(footer)
    _write_out(args.out, rows, f"{text}\n\n{footer}")
    return 0


def _write_out(out: Path | None, rows: list[dict], text: str) -> None:
    """The study's result as files: ``table.md`` (Markdown) and ``runs.jsonl`` (one run a line)."""
    if out is None:
        return
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(text + "\n")
    (out / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


if __name__ == "__main__":
    raise SystemExit(main())
