#!/usr/bin/env python3
"""Patrols of a thruster world the simulator did not make: false alarms and detection.

Models are trained as a user would on their own thruster (``thruster-fdd train nominal`` on
the healthy traces, ``train classifier`` on all) on ``t200_world.py rich`` traces of six units,
then patrols of other units of the same world (``t200_world.patrol``) run through the vehicle's
residual and decision code: healthy patrols (half at a constant 15.3 V, the training voltage
of the faults, half with the supply drifting from 16 to 12.5 V) and faulty patrols that lose
one or two blades or foul at ``--onset-s`` (15.3 V). A fault published before the onset of a
faulty patrol is a false alarm on a healthy unit and is counted with the healthy patrols.

Written to ``--out``: ``summary.md``, ``summary.json``, ``runs.json``; the training traces in
``train/`` and the models in ``models/`` unless ``--models`` names trained ones.

Usage: ``python scripts/t200_study.py --out out/t200 [--models DIR] [--jobs 2]`` (about 40
minutes on two cores, most of it training the nominal model; the patrols take a few minutes).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import t200_world as world
from patrol_study import DETECT_WITHIN_S, poisson_upper

from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.diagnosis.stream import LOW_EXCITATION, OUTSIDE_TRAINING
from thruster_fdd.core.labels import FAULT_CLASSES, UNKNOWN
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.cli import main as cli
from thruster_fdd_shore.core.diagnosis.offline import trace_decisions

FAULT_SUPPLY_V = 15.3


def train(out: Path, first_unit: int) -> Path:
    """Write the rich training traces of six units and train both models into ``out/models``."""
    data = out / "train"
    data.mkdir(parents=True, exist_ok=True)
    run = [sys.executable, str(Path(world.__file__)), "rich", "--out", str(data)]
    subprocess.run([*run, "--first-seed", str(first_unit)], check=True)
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
    """One patrol of one unit through the vehicle's code: fault time, unknown share, delays."""
    seed, seconds, fault = job["seed"], job["seconds"], job["fault"]
    cmd = world.patrol(seconds, 900 + seed)
    supply = (
        np.linspace(16.0, 12.5, len(cmd)) if job["drift"] else np.full(len(cmd), FAULT_SUPPLY_V)
    )
    onset = job["onset_s"] if fault else None
    rpm, cur, v = world.simulate(cmd, supply, "nominal_15v", seed, 77 + seed, onset, fault)
    t = np.arange(len(cmd)) / world.RATE
    trace = Trace(t=t, command=cmd, voltage=v, rpm=rpm, current=cur)
    models = Path(job["models"])
    decisions = trace_decisions(
        trace, NominalModel.load(models / "nominal"), ClassifierModel.load(models / "classifier")
    )
    hop = float(np.median(np.diff([d.t_s for d in decisions])))
    healthy_end = onset if onset is not None else np.inf
    before = [d for d in decisions if d.t_s < healthy_end]
    is_fault = [d.label in FAULT_CLASSES for d in before]
    out: dict[str, Any] = {
        **{k: job[k] for k in ("seed", "fault", "drift", "seconds")},
        "healthy_s": float(min(seconds, healthy_end)),
        "fault_s": hop * sum(is_fault),
        "fault_episodes": sum(
            1 for i, f in enumerate(is_fault) if f and not (i and is_fault[i - 1])
        ),
        "fault_labels": sorted({d.label for d in before if d.label in FAULT_CLASSES}),
        "unknown_fraction": sum(d.label == UNKNOWN for d in before) / max(len(before), 1),
        "max_fault_evidence": max((d.fault_evidence for d in before), default=0.0),
    }
    if onset is None:
        return out
    after = [d for d in decisions if d.t_start_s >= onset]
    covered = [d for d in after if d.reason not in (OUTSIDE_TRAINING, LOW_EXCITATION)]
    first = next((d for d in after if d.label in FAULT_CLASSES), None)
    out["first_fault"] = first.label if first else None
    out["covered_delay_s"] = (
        None if first is None else hop * sum(1 for d in covered if d.t_s < first.t_s)
    )
    out["delay_s"] = None if first is None or not covered else first.t_s - covered[0].t_s
    if first is not None:
        later = [d for d in after if d.t_s >= first.t_s]
        labelled = [d for d in later if d.label != UNKNOWN]
        out["right_of_all"] = sum(d.label == fault for d in later) / len(later)
        out["right_of_labelled"] = sum(d.label == fault for d in labelled) / max(len(labelled), 1)
    return out


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
    p.add_argument("--jobs", type=int, default=2, help="worker processes")
    args = p.parse_args(argv)
    if not world.DATA.is_dir():
        print(f"t200_study: the T200 workbook sheets are not at {world.DATA}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    models = args.models or train(args.out, args.train_unit)
    jobs = [
        {"seed": args.healthy_unit + i, "fault": None, "drift": i % 2 == 1,
         "seconds": args.healthy_s, "onset_s": None, "models": str(models)}
        for i in range(args.healthy_runs)
    ] + [
        {"seed": args.faulty_unit + k, "fault": list(world.FAULTS)[k % len(world.FAULTS)],
         "drift": False, "seconds": args.faulty_s, "onset_s": args.onset_s, "models": str(models)}
        for k in range(args.faulty_runs)
    ]  # fmt: skip
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        runs = []
        for r in pool.map(patrol_run, jobs):
            runs.append(r)
            print(f"[t200] unit {r['seed']} {r['fault'] or 'healthy'} done", file=sys.stderr)
    summary = summarize(runs)
    model_id = ClassifierModel.load(models / "classifier").model_id
    summary["classifier"] = model_id
    write_text(args.out / "summary.json", json.dumps(summary, indent=2) + "\n")
    write_text(args.out / "runs.json", json.dumps(runs, indent=1))
    write_text(args.out / "summary.md", markdown(summary, model_id))
    print(markdown(summary, model_id))
    return 0


if __name__ == "__main__":
    sys.exit(main())
