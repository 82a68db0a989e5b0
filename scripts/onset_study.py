"""How well ``diagnose`` dates a fault: its ``first_fault`` (published time and estimated onset,
``core.diagnosis.offline.first_fault``) against the simulated onset.

For every seed and fault class, simulates a t100 unit that is healthy until an onset between 60
and 100 s and faulty after it (multilevel commands, 200 s at 10 Hz), diagnoses it with the
committed models through the nodes' code path and prints, per class and overall: how often the
first published fault is the simulated one, the detection delay (published - onset) and the
onset estimate's error (median, median absolute, 90th percentile of the absolute). With
``--out DIR`` it also writes the table as ``DIR/table.md`` and every run as ``DIR/runs.json``.

Usage (after ``. scripts/bootstrap.sh``)::

    python scripts/onset_study.py [--seeds 12] [--first-seed 800] [--models models] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.labels import FAULT_CLASSES
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd_shore.core.diagnosis.offline import first_fault, trace_decisions
from thruster_fdd_shore.core.sim.scenario import run_scenario


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=12)
    p.add_argument("--first-seed", type=int, default=800)
    p.add_argument("--models", type=Path, default=default_models_dir())
    p.add_argument("--out", type=Path, help="also write table.md and runs.json into this folder")
    args = p.parse_args(argv)
    nominal = NominalModel.load(args.models / "nominal")
    classifier = ClassifierModel.load(args.models / "classifier")
    rows: list[tuple[str, str | None, float, float, float]] = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        onset = 60.0 + (seed % 5) * 10.0
        for condition in FAULT_CLASSES:
            trace = run_scenario(
                "t100",
                "nominal_15v",
                signal="multilevel",
                duration_s=200.0,
                seed=seed,
                fault_at_s=onset,
                fault_condition=condition,
            )
            fault = first_fault(trace_decisions(trace, nominal, classifier))
            if fault is None:
                rows.append((condition, None, onset, np.nan, np.nan))
            else:
                rows.append((condition, fault["label"], onset, fault["t"], fault["onset_t"]))
    lines = [
        "| fault | runs | first fault named right | delay median s | onset error median s "
        "| median abs. s | p90 abs. s |",
        "|---|---|---|---|---|---|---|",
    ]
    for condition in (*FAULT_CLASSES, "all"):
        sel = [r for r in rows if condition in ("all", r[0])]
        found = [r for r in sel if r[1] is not None]
        delay = np.array([r[3] - r[2] for r in found])
        error = np.array([r[4] - r[2] for r in found])
        right = sum(r[1] == r[0] for r in sel)
        lines.append(
            f"| {condition} | {len(sel)} | {right}/{len(sel)} (a fault: {len(found)}) | "
            f"{np.median(delay):.1f} | {np.median(error):+.1f} | {np.median(np.abs(error)):.1f} | "
            f"{np.percentile(np.abs(error), 90):.1f} |"
        )
    table = "\n".join(lines)
    print(table)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "table.md").write_text(table + "\n")
        runs = [
            {"condition": c, "first_fault": label, "onset_s": onset, "published_s": t,
             "onset_estimate_s": est}
            for c, label, onset, t, est in rows
        ]  # fmt: skip
        document = {"command": vars(args) | {"models": str(args.models), "out": str(args.out)},
                    "runs": runs}  # fmt: skip
        (args.out / "runs.json").write_text(json.dumps(document, allow_nan=True) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
