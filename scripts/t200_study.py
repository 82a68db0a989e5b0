#!/usr/bin/env python3
"""Patrols of a thruster world the simulator did not make: false alarms and detection.

Models are trained as a user would on their own thruster (``thruster-fdd train nominal`` on
the healthy traces, ``train classifier`` on all) on ``t200_world.py rich`` traces of six units,
then patrols of other units of the same world (``t200_world.patrol``) run through the vehicle's
residual and decision code: healthy patrols (half at a constant 15.3 V, the training voltage
of the faults, half with the supply drifting from 16 to 12.5 V) and faulty patrols that lose
one or two blades or foul at ``--onset-s`` (15.3 V). A fault published before the onset of a
faulty patrol is a false alarm on a healthy unit and is counted with the healthy patrols.
Each healthy stretch's quiet allowance is reported too: the smallest ``unit_allowance`` with
which it publishes no fault; the largest over the units is what the classifier needs
(``--unit-allowance`` reruns the patrols with another; docs/diagnosis.md).

Written to ``--out``: ``summary.md``, ``summary.json``, ``runs.json``; the training traces in
``train/`` and the models in ``models/`` unless ``--models`` names trained ones.

Usage: ``python scripts/t200_study.py --out out/t200 [--models DIR] [--jobs 2]`` (about 40
minutes on two cores, most of it training the nominal model; the patrols take a few minutes).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import t200_world as world
from patrol_study import DETECT_WITHIN_S, detection_metrics, healthy_metrics, poisson_upper

from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.diagnosis.stream import LLR_CLIP, UNIT_ALLOWANCE
from thruster_fdd.core.labels import FAULT_CLASSES
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.cli import main as cli
from thruster_fdd_shore.core.diagnosis.offline import trace_decisions


def train(out: Path, first_unit: int) -> Path:
    """Write the rich training traces of six units and train both models into ``out/models``."""
    data = out / "train"
    data.mkdir(parents=True, exist_ok=True)
    world.write_training(data, range(first_unit, first_unit + 6), paper=False)
    models = out / "models"
    healthy = sorted(str(p) for p in data.glob("nominal_*.csv"))
    for args in (
        # The card's validation pass would double the training time and change no weight.
        ["nominal", "--data", *healthy, "--out", str(models / "nominal"),
         "--validation-fraction", "0"],
        ["classifier", "--data", str(data), "--nominal", str(models / "nominal"),
         "--out", str(models / "classifier")],
    ):  # fmt: skip
        if cli(["train", *args]) != 0:
            raise SystemExit(f"thruster-fdd train {args[0]} failed")
    return models


def patrol_run(job: dict[str, Any]) -> dict[str, Any]:
    """One patrol of one unit through the vehicle's code: the healthy part's fault time and
    unknown share (``patrol_study.healthy_metrics``); after an onset, the detection
    (``patrol_study.detection_metrics``)."""
    fault, onset = job["fault"], job["onset_s"]
    cmd, rpm, cur, v = world.patrol_unit(
        job["seed"], job["seconds"], drift=job["drift"], fault=fault, fault_at=onset
    )
    t = np.arange(len(cmd)) / world.RATE
    trace = Trace(t=t, command=cmd, voltage=v, rpm=rpm, current=cur)
    models = Path(job["models"])
    decisions = trace_decisions(
        trace,
        NominalModel.load(models / "nominal"),
        ClassifierModel.load(models / "classifier"),
        unit_allowance=job["unit_allowance"],
    )
    healthy_end = min(onset, job["seconds"]) if fault else job["seconds"]
    out: dict[str, Any] = {
        **{k: job[k] for k in ("seed", "fault", "drift", "seconds")},
        "healthy_s": float(healthy_end),
        **healthy_metrics([d for d in decisions if d.t_s < healthy_end]),
    }
    return {**out, **detection_metrics(decisions, onset, fault)} if fault else out


def summarize(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The tables as data: every healthy stretch, then the faulty patrols by fault."""
    hours = sum(r["healthy_s"] for r in runs) / 3600.0
    episodes = sum(r["fault_episodes"] for r in runs)
    healthy = {
        "units": len(runs),
        "hours": hours,
        "fault_seconds": sum(r["fault_s"] for r in runs),
        "fault_episodes": episodes,
        "units_with_a_fault": sum(1 for r in runs if r["fault_episodes"]),
        "episodes_per_hour_upper95": poisson_upper(episodes, hours),
        "unknown_fraction": float(np.mean([r["unknown_fraction"] for r in runs])),
        **_quiet_spread(runs),
    }
    faulty = {}
    for name in FAULT_CLASSES:
        rs = [r for r in runs if r["fault"] == name]
        covered = [r["covered_delay_s"] for r in rs if r["covered_delay_s"] is not None]
        walls = [r["delay_s"] for r in rs if r["delay_s"] is not None]
        faulty[name] = {
            "runs": len(rs),
            "first_fault_right": sum(r["first_fault"] == name for r in rs),
            "within_60s_covered": sum(d <= DETECT_WITHIN_S for d in covered),
            "median_covered_delay_s": float(np.median(covered)) if covered else None,
            "median_delay_s": float(np.median(walls)) if walls else None,
            "right_of_all": float(np.mean([r.get("right_of_all", 0.0) for r in rs])),
            "right_of_labelled": float(np.mean([r.get("right_of_labelled", 0.0) for r in rs])),
        }
    return {"healthy": healthy, "faulty": faulty}


def _quiet_spread(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Median and largest quiet allowance (nats) of the healthy stretches, and whose."""
    known = [r for r in runs if r["quiet_allowance"] is not None]
    if not known:
        return {"quiet_allowance_median": None, "quiet_allowance_largest": None}
    top = max(known, key=lambda r: r["quiet_allowance"])
    return {
        "quiet_allowance_median": float(np.median([r["quiet_allowance"] for r in known])),
        "quiet_allowance_largest": top["quiet_allowance"],
        "quiet_allowance_largest_unit": top["seed"],
    }


def markdown(summary: dict[str, Any], model_id: str) -> str:
    """``summary.md``."""
    h = summary["healthy"]
    lines = [
        f"Classifier `{model_id}`.",
        "",
        "| healthy operation | units | hours | fault published, s | episodes | units with a fault "
        "| episodes/h (95 % upper) | unknown |",
        "|---|---|---|---|---|---|---|---|",
        f"| patrols and faulty patrols before the onset | {h['units']} | {h['hours']:.1f} | "
        f"{h['fault_seconds']:.0f} | {h['fault_episodes']} | {h['units_with_a_fault']} | "
        f"{h['episodes_per_hour_upper95']:.3f} | {100 * h['unknown_fraction']:.1f} % |",
        "",
        _quiet_line(summary),
        "",
        "| faulty patrols | runs | first fault right | within 60 s of covered work | median delay: "
        "covered work / wall, s | right class after (all / labelled) |",
        "|---|---|---|---|---|---|",
    ]
    for name, f in summary["faulty"].items():
        delays = " / ".join(
            "-" if f[k] is None else f"{f[k]:.0f}"
            for k in ("median_covered_delay_s", "median_delay_s")
        )
        lines.append(
            f"| {name} | {f['runs']} | {f['first_fault_right']}/{f['runs']} | "
            f"{f['within_60s_covered']}/{f['runs']} | {delays} | "
            f"{100 * f['right_of_all']:.0f} % / {100 * f['right_of_labelled']:.0f} % |"
        )
    return "\n".join(lines) + "\n"


def _quiet_line(summary: dict[str, Any]) -> str:
    """What the healthy units' quiet allowances say about the allowance."""
    h = summary["healthy"]
    if h["quiet_allowance_largest"] is None:
        return "No healthy unit had an informative window."
    return (
        f"Smallest `unit_allowance` that keeps a healthy unit free of faults: median "
        f"{h['quiet_allowance_median']:.2f}, largest {h['quiet_allowance_largest']:.2f} nats "
        f"(unit {h['quiet_allowance_largest_unit']}); this run used "
        f"{summary['unit_allowance']:g}."
    )


def main(argv: list[str] | None = None) -> int:
    """Run the study (module docstring)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True, help="folder for the tables")
    p.add_argument("--models", type=Path, help="trained nominal/ and classifier/ (default: train)")
    p.add_argument("--train-unit", type=int, default=10, help="first of the six training units")
    p.add_argument("--healthy-unit", type=int, default=400, help="first healthy patrol unit")
    p.add_argument("--healthy-runs", type=int, default=48, help="healthy patrols")
    p.add_argument("--healthy-s", type=float, default=900.0, help="length of a healthy patrol, s")
    p.add_argument("--faulty-unit", type=int, default=200, help="first faulty patrol unit")
    p.add_argument("--faulty-runs", type=int, default=36, help="faulty patrols (classes in turn)")
    p.add_argument("--faulty-s", type=float, default=1200.0, help="length of a faulty patrol, s")
    p.add_argument("--onset-s", type=float, default=120.0, help="fault onset, s")
    p.add_argument(
        "--unit-allowance",
        type=float,
        default=UNIT_ALLOWANCE,
        help="the classifier's unit_allowance, nats per window length",
    )
    p.add_argument("--jobs", type=int, default=2, help="worker processes")
    args = p.parse_args(argv)
    if not world.DATA.is_dir():
        print(f"t200_study: the T200 workbook sheets are not at {world.DATA}", file=sys.stderr)
        return 2
    if not (math.isfinite(args.unit_allowance) and 0.0 <= args.unit_allowance <= LLR_CLIP):
        print(f"t200_study: --unit-allowance must be in [0, {LLR_CLIP:.1f}]", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    models = args.models or train(args.out, args.train_unit)
    common = {"onset_s": args.onset_s, "models": str(models), "unit_allowance": args.unit_allowance}
    jobs = [
        {**common, "seed": args.healthy_unit + i, "fault": None, "drift": i % 2 == 1,
         "seconds": args.healthy_s}
        for i in range(args.healthy_runs)
    ] + [
        {**common, "seed": args.faulty_unit + k, "fault": list(world.FAULTS)[k % len(world.FAULTS)],
         "drift": False, "seconds": args.faulty_s}
        for k in range(args.faulty_runs)
    ]  # fmt: skip
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        runs = []
        for r in pool.map(patrol_run, jobs):
            runs.append(r)
            print(f"[t200] unit {r['seed']} {r['fault'] or 'healthy'} done", file=sys.stderr)
    summary = {**summarize(runs), "unit_allowance": args.unit_allowance}
    model_id = ClassifierModel.load(models / "classifier").model_id
    summary["classifier"] = model_id
    write_text(args.out / "summary.json", json.dumps(summary, indent=2) + "\n")
    write_text(args.out / "runs.json", json.dumps(runs, indent=1))
    text = markdown(summary, model_id)
    write_text(args.out / "summary.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
