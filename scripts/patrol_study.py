#!/usr/bin/env python3
"""Patrol study: does the diagnosis cry wolf on long healthy patrols, and does it find faults?

Healthy patrols (``signals.patrol``: idle holds, creeping, long cruise legs, turns, short
reversals; the supply constant at 15 V or drifting down with the battery) of units never used
in training, half of them structural variants of the t100 (a second ESC stage, an idle current
that grows with speed, no regeneration), run through the vehicle's own residual and decision
code with a classifier trained on the paper's protocol (three units, a 0.01 Hz sine, 200 s per
class) or any exported classifier. Faulty patrols of more unseen units lose one or two blades
or foul at a given time. Windows of unseen units on the sine and multilevel profiles give the
expected calibration error and a reliability plot.

Written to ``--out``: ``summary.md`` and ``summary.json`` (the tables), ``runs.json`` (every
run), ``reliability.png``; the trained classifier in ``classifier/`` when ``--train paper``.

Usage: ``python scripts/patrol_study.py --out out/patrol [--train paper | --classifier DIR]
[--healthy-runs 20 --patrol-s 3600] [--faulty-runs 8] [--first-seed 5000] [--jobs 2]``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.diagnosis.stream import LOW_EXCITATION, OUTSIDE_TRAINING, Decision
from thruster_fdd.core.labels import CLASS_NAMES, FAULT_CLASSES, UNKNOWN
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.diagnosis.metrics import expected_calibration_error, reliability
from thruster_fdd_shore.core.diagnosis.offline import quiet_allowance, trace_decisions
from thruster_fdd_shore.core.sim.config import SimConfig, load_config
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator
from thruster_fdd_shore.core.sim.scenario import run_scenario
from thruster_fdd_shore.core.sim.signals import make_signal

RATE_HZ = 10.0
PAPER_UNITS = (300, 301, 302)
"""Training units of the paper's protocol (disjoint from every study unit)."""

VARIANTS: dict[str, dict[str, Any]] = {
    "t100": {},
    "esc_stage": {"esc_tau2_s": 0.08},
    "idle_current": {"i_idle_per_krpm_a": 0.05},
    "no_regen": {"regen": False},
}
"""Structural variants of the t100 (``SimConfig.structure`` fields) the patrols run on."""

DETECT_WITHIN_S = 60.0


def variant_config(name: str) -> SimConfig:
    """The t100 with the structure changes of ``VARIANTS[name]``."""
    base = load_config("t100")
    return replace(base, structure=replace(base.structure, **VARIANTS[name]))


def patrol_trace(
    config: SimConfig,
    seed: int,
    duration_s: float,
    *,
    drift: bool,
    condition: str = "nominal_15v",
    fault: str | None = None,
    onset_s: float = 0.0,
) -> Trace:
    """One patrol of unit ``seed``: healthy (``condition``), or ``fault`` from ``onset_s``;
    with ``drift`` the supply falls linearly from 16.0 to 12.5 V over the patrol."""
    t, command = make_signal("patrol", duration_s, RATE_HZ, seed=seed)
    sim = ThrusterSimulator(config, condition, seed=seed)
    rows = []
    previous = t[0]
    for ti, ci in zip(t.tolist(), command.tolist(), strict=True):
        if fault is not None and ti >= onset_s and sim.condition != fault:
            sim.set_condition(fault)
        if drift and round(ti * RATE_HZ) % 100 == 0:
            sim.set_voltage(16.0 - 3.5 * ti / duration_s)
        s = sim.step(ci, ti - previous)
        previous = ti
        rows.append((s.t, s.command, s.voltage, s.rpm, s.current))
    a = np.asarray(rows)
    return Trace(t=a[:, 0], command=a[:, 1], voltage=a[:, 2], rpm=a[:, 3], current=a[:, 4])


def _models(nominal_dir: str, classifier_dir: str) -> tuple[NominalModel, ClassifierModel]:
    return NominalModel.load(nominal_dir), ClassifierModel.load(classifier_dir)


def healthy_run(job: dict[str, Any]) -> dict[str, Any]:
    """False alarms, unknown share and reasons of one healthy patrol."""
    nominal, classifier = _models(job["nominal"], job["classifier"])
    trace = patrol_trace(
        variant_config(job["variant"]), job["seed"], job["duration_s"], drift=job["drift"]
    )
    return {**job, **healthy_metrics(trace_decisions(trace, nominal, classifier))}


def healthy_metrics(decisions: list[Decision]) -> dict[str, Any]:
    """Fault time (s) and episodes, unknown share and reasons of decisions on a healthy unit,
    and the smallest ``unit_allowance`` that keeps it free of faults (``quiet_allowance``,
    nats; None without an informative window; docs/diagnosis.md)."""
    labels = [d.label for d in decisions]
    fault = [label in FAULT_CLASSES for label in labels]
    episodes = sum(1 for i, f in enumerate(fault) if f and (i == 0 or not fault[i - 1]))
    reasons: dict[str, int] = {}
    for d in decisions:
        if d.label == UNKNOWN:
            reasons[d.reason] = reasons.get(d.reason, 0) + 1
    return {
        "decisions": len(decisions),
        "fault_s": float(sum(fault)) * _hop(decisions),
        "fault_episodes": episodes,
        "fault_labels": sorted({x for x in labels if x in FAULT_CLASSES}),
        "unknown_fraction": labels.count(UNKNOWN) / max(len(labels), 1),
        "reasons": reasons,
        "max_fault_evidence": max((d.fault_evidence for d in decisions), default=0.0),
        "quiet_allowance": quiet_allowance(decisions),
    }


def detection_metrics(decisions: list[Decision], onset: float, fault: str) -> dict[str, Any]:
    """When a fault starting at ``onset`` (s) was published, after how much covered work, and
    how much of the time after it the label was ``fault``."""
    after = [d for d in decisions if d.t_start_s >= onset]
    informative = [d for d in after if d.reason not in (OUTSIDE_TRAINING, LOW_EXCITATION)]
    working = informative[0].t_s if informative else None
    first = next((d for d in after if d.label in FAULT_CLASSES), None)
    detected = None if first is None else first.t_s
    out: dict[str, Any] = {
        "first_covered_working_s": working,
        "detected_s": detected,
        "first_fault": None if first is None else first.label,
        "delay_s": None if detected is None or working is None else detected - working,
        "covered_delay_s": None
        if detected is None
        else _hop(decisions) * sum(1 for d in informative if d.t_s < detected),
    }
    if detected is not None:
        later = [d for d in after if d.t_s >= detected]
        right = sum(d.label == fault for d in later)
        labelled = sum(d.label != UNKNOWN for d in later)
        out["right_of_all"] = right / len(later)
        out["right_of_labelled"] = right / max(labelled, 1)
        out["unknown_after"] = 1.0 - labelled / len(later)
    return out


def _hop(decisions: list[Decision]) -> float:
    return float(np.median(np.diff([d.t_s for d in decisions]))) if len(decisions) > 1 else 1.0


def faulty_run(job: dict[str, Any]) -> dict[str, Any]:
    """Detection delay after the first covered working window past the onset, and the share
    of the right class after detection, of one faulty patrol."""
    nominal, classifier = _models(job["nominal"], job["classifier"])
    trace = patrol_trace(
        variant_config(job["variant"]),
        job["seed"],
        job["duration_s"],
        drift=False,
        fault=job["fault"],
        onset_s=job["onset_s"],
    )
    decisions = trace_decisions(trace, nominal, classifier)
    onset = job["onset_s"]
    return {
        **job,
        "false_before_onset_s": float(
            sum(d.label in FAULT_CLASSES for d in decisions if d.t_s < onset)
        ),
        **detection_metrics(decisions, onset, job["fault"]),
    }


def calibration_windows(job: dict[str, Any]) -> dict[str, Any]:
    """Window probabilities and truths of one unseen unit on the sine and multilevel
    profiles (every class)."""
    nominal, classifier = _models(job["nominal"], job["classifier"])
    probs, truth, covered = [], [], []
    for signal in ("sine:0.01", "multilevel"):
        for cond in CLASS_NAMES:
            trace = run_scenario("t100", cond, signal=signal, duration_s=300.0, seed=job["seed"])
            for d in trace_decisions(trace, nominal, classifier):
                probs.append([d.probabilities[c] for c in classifier.class_names])
                truth.append(classifier.class_names.index(cond))
                covered.append(d.covered)
    return {"probs": probs, "truth": truth, "covered": covered}


def demo_run(job: dict[str, Any]) -> dict[str, Any]:
    """The README demo's scenario offline (mission profile at 50 Hz, two blades lost at 30 s,
    90 s): the labels published before the onset."""
    nominal, classifier = _models(job["nominal"], job["classifier"])
    trace = run_scenario(
        "t100", "nominal_15v", signal="mission", duration_s=90.0, rate_hz=50.0,
        seed=job["seed"], fault_at_s=30.0, fault_condition="broken_blade_2",
    )  # fmt: skip
    decisions = trace_decisions(trace, nominal, classifier)
    before = sorted({d.label for d in decisions if d.t_s < 30.0})
    after = [d.label for d in decisions if d.t_s >= 30.0]
    return {
        "seed": job["seed"],
        "labels_before_onset": before,
        "fault_before_onset": any(x in FAULT_CLASSES for x in before),
        "broken_blade_2_after": "broken_blade_2" in after,
    }


def poisson_upper(events: int, exposure: float, confidence: float = 0.95) -> float:
    """One-sided upper confidence bound of a Poisson rate (events per unit of exposure)."""
    from scipy.stats import chi2

    return float(chi2.ppf(confidence, 2 * events + 2) / (2.0 * exposure))


def train_paper(nominal_dir: Path, out: Path) -> Path:
    """Train a classifier on the paper's protocol into ``out``."""
    from thruster_fdd_shore.core.diagnosis.training import train_classifier

    traces = [
        run_scenario(
            "t100", cond, signal="sine:0.01", duration_s=200.0, seed=seed, thruster_id=f"u{seed}"
        )
        for seed in PAPER_UNITS
        for cond in CLASS_NAMES
    ]
    train_classifier(traces, nominal_dir, out, seed=0, progress=True)
    return out


def summarize(
    healthy: list[dict], faulty: list[dict], cal: dict[str, Any], demo: list[dict]
) -> dict[str, Any]:
    """The study's tables as data."""
    hours = sum(r["duration_s"] for r in healthy) / 3600.0
    episodes = sum(r["fault_episodes"] for r in healthy)
    fault_s = sum(r["fault_s"] for r in healthy)
    unknown = float(np.mean([r["unknown_fraction"] for r in healthy])) if healthy else 0.0
    by_fault: dict[str, dict[str, Any]] = {}
    for name in FAULT_CLASSES:
        runs = [r for r in faulty if r["fault"] == name]
        if not runs:
            continue
        delays = [r["delay_s"] for r in runs if r["delay_s"] is not None]
        covered_delays = [r["covered_delay_s"] for r in runs if r["covered_delay_s"] is not None]
        within = sum(1 for d in covered_delays if d <= DETECT_WITHIN_S)
        by_fault[name] = {
            "runs": len(runs),
            "detected_within_60s": within,
            "median_delay_s": float(np.median(delays)) if delays else None,
            "median_covered_delay_s": float(np.median(covered_delays)) if covered_delays else None,
            "right_of_all": float(np.mean([r.get("right_of_all", 0.0) for r in runs])),
            "right_of_labelled": float(np.mean([r.get("right_of_labelled", 0.0) for r in runs])),
            "false_before_onset_s": float(sum(r["false_before_onset_s"] for r in runs)),
        }
    probs, truth = np.asarray(cal["probs"]), np.asarray(cal["truth"])
    covered = np.asarray(cal["covered"], dtype=bool)
    return {
        "healthy": {
            "hours": hours,
            "fault_seconds": fault_s,
            "fault_episodes": episodes,
            "episodes_per_hour_upper95": poisson_upper(episodes, hours) if hours else None,
            "unknown_fraction": unknown,
        },
        "faulty": by_fault,
        "demo": {
            "seeds": len(demo),
            "fault_before_onset": sum(r["fault_before_onset"] for r in demo),
            "broken_blade_2_after": sum(r["broken_blade_2_after"] for r in demo),
        },
        "calibration": {
            "windows": len(truth),
            "ece": expected_calibration_error(probs, truth),
            "reliability": reliability(probs, truth),
            "covered_windows": int(covered.sum()),
            "ece_covered": expected_calibration_error(probs[covered], truth[covered])
            if covered.any()
            else None,
        },
    }


def markdown(summary: dict[str, Any], classifier: str) -> str:
    """``summary.md``."""
    h = summary["healthy"]
    lines = [
        f"Classifier `{classifier}`.",
        "",
        "| healthy patrols | hours | fault published, s | episodes | episodes/h (95 % upper) "
        "| unknown |",
        "|---|---|---|---|---|---|",
        f"| unseen units and variants | {h['hours']:.1f} | {h['fault_seconds']:.0f} | "
        f"{h['fault_episodes']} | {h['episodes_per_hour_upper95']:.3f} | "
        f"{100 * h['unknown_fraction']:.1f} % |",
        "",
        "| faulty patrols | runs | published within 60 s of covered work | median delay: "
        "covered work / wall, s | right class after (all / labelled) | fault before onset, s |",
        "|---|---|---|---|---|---|",
    ]
    for name, f in summary["faulty"].items():
        delay = (
            "-"
            if f["median_delay_s"] is None
            else f"{f['median_covered_delay_s']:.0f} / {f['median_delay_s']:.0f}"
        )
        lines.append(
            f"| {name} | {f['runs']} | {f['detected_within_60s']}/{f['runs']} | {delay} | "
            f"{100 * f['right_of_all']:.0f} % / {100 * f['right_of_labelled']:.0f} % | "
            f"{f['false_before_onset_s']:.0f} |"
        )
    c = summary["calibration"]
    demo = summary["demo"]
    lines += ["", f"README demo scenario offline: a fault label before the onset in "
              f"{demo['fault_before_onset']} of {demo['seeds']} seeds; broken_blade_2 published "
              f"after it in {demo['broken_blade_2_after']}."]  # fmt: skip
    covered = "-" if c["ece_covered"] is None else f"{c['ece_covered']:.3f}"
    lines += ["", f"Expected calibration error on unseen units (sine 0.01 Hz and multilevel): "
              f"{c['ece']:.3f} over all {c['windows']} windows, {covered} over the "
              f"{c['covered_windows']} covered ones."]  # fmt: skip
    return "\n".join(lines) + "\n"


def plot_reliability(summary: dict[str, Any], path: Path) -> None:
    """The reliability diagram of the unseen units' windows."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = summary["calibration"]["reliability"]
    fig, ax = plt.subplots(figsize=(4.5, 4.5))
    ax.plot([0, 1], [0, 1], color="0.6", linestyle="--", label="perfectly calibrated")
    x = [r["confidence"] for r in rows]
    y = [r["accuracy"] for r in rows]
    ax.plot(x, y, "-", color="tab:blue", alpha=0.5)
    ax.scatter(x, y, s=[20 + 600 * r["share"] for r in rows], color="tab:blue",
               label="windows (area: share of windows)")  # fmt: skip
    ax.set_xlabel("published probability of the top class")
    ax.set_ylabel("share of windows where it is right")
    ax.set_title(f"Reliability, unseen units (ECE {summary['calibration']['ece']:.3f})")
    ax.legend(loc="upper left", markerscale=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Run the study (module docstring)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True, help="folder for the tables and plots")
    p.add_argument("--train", choices=("paper",), help="train a classifier on the paper protocol")
    p.add_argument("--classifier", type=Path, help="exported classifier (default: the models')")
    p.add_argument("--nominal", type=Path, default=default_models_dir() / "nominal")
    p.add_argument("--healthy-runs", type=int, default=20, help="healthy patrols")
    p.add_argument("--patrol-s", type=float, default=3600.0, help="length of a healthy patrol, s")
    p.add_argument("--faulty-runs", type=int, default=8, help="faulty patrols per fault class")
    p.add_argument("--faulty-s", type=float, default=900.0, help="length of a faulty patrol, s")
    p.add_argument("--onset-s", type=float, default=120.0, help="fault onset in a faulty patrol")
    p.add_argument("--calibration-units", type=int, default=3, help="unseen units for the ECE")
    p.add_argument("--first-seed", type=int, default=5000, help="first unit seed")
    p.add_argument("--demo-seeds", type=int, default=10, help="seeds 0.. of the README demo")
    p.add_argument("--jobs", type=int, default=2, help="worker processes")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.train == "paper":
        classifier = train_paper(args.nominal, args.out / "classifier")
    else:
        classifier = args.classifier or default_models_dir() / "classifier"
    common = {"nominal": str(args.nominal), "classifier": str(classifier)}
    names = list(VARIANTS)
    seed = args.first_seed
    healthy_jobs = []
    for i in range(args.healthy_runs):
        variant = "t100" if i % 2 == 0 else names[1 + (i // 2) % (len(names) - 1)]
        healthy_jobs.append(
            {**common, "seed": seed + i, "variant": variant, "drift": i % 4 in (1, 2),
             "duration_s": args.patrol_s}
        )  # fmt: skip
    seed += args.healthy_runs
    faulty_jobs = []
    for k, fault in enumerate(FAULT_CLASSES):
        for i in range(args.faulty_runs):
            faulty_jobs.append(
                {**common, "seed": seed + k * args.faulty_runs + i, "fault": fault,
                 "variant": names[i % len(names)], "duration_s": args.faulty_s,
                 "onset_s": args.onset_s}
            )  # fmt: skip
    seed += len(FAULT_CLASSES) * args.faulty_runs
    cal_jobs = [{**common, "seed": seed + i} for i in range(args.calibration_units)]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        healthy = list(pool.map(healthy_run, healthy_jobs))
        print(f"[patrol] {len(healthy)} healthy patrols done", file=sys.stderr)
        faulty = list(pool.map(faulty_run, faulty_jobs))
        print(f"[patrol] {len(faulty)} faulty patrols done", file=sys.stderr)
        parts = list(pool.map(calibration_windows, cal_jobs))
        demo = list(pool.map(demo_run, [{**common, "seed": s} for s in range(args.demo_seeds)]))
    cal = {
        "probs": [row for x in parts for row in x["probs"]],
        "truth": [y for x in parts for y in x["truth"]],
        "covered": [c for x in parts for c in x["covered"]],
    }
    summary = summarize(healthy, faulty, cal, demo)
    model_id = ClassifierModel.load(classifier).model_id
    summary["classifier"] = model_id
    write_text(args.out / "summary.json", json.dumps(summary, indent=2) + "\n")
    runs = {"healthy": healthy, "faulty": faulty, "demo": demo}
    write_text(args.out / "runs.json", json.dumps(runs, indent=1))
    write_text(args.out / "summary.md", markdown(summary, model_id))
    plot_reliability(summary, args.out / "reliability.png")
    print(markdown(summary, model_id))
    return 0 if math.isfinite(summary["calibration"]["ece"]) else 1


if __name__ == "__main__":
    sys.exit(main())
