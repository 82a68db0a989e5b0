"""``thruster-fdd diagnose``: offline diagnosis of a trace file through the nodes' code path."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from thruster_fdd.commands.common import EXIT_OK, positive_float
from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.errors import BadInputError

NAME = "diagnose"
HELP = "offline diagnosis of a trace file (per window and overall, JSON)"
DESCRIPTION = (
    "Diagnose a trace CSV / MCAP file with the exported models (DIR/nominal and "
    "DIR/classifier), through the same residual and window code as the nodes: one decision per "
    "--hop seconds over the classifier's window, and an overall label. JSON: {overall: {label, "
    "confidence}, windows: [{t_start, t_end, label, probabilities}]}."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd diagnose``."""
    p.add_argument("trace", type=Path, metavar="TRACE")
    p.add_argument("--models", type=Path, default=Path("models"), metavar="DIR")
    p.add_argument("--json", type=Path, metavar="OUT")
    p.add_argument("--hop", type=positive_float, default=1.0, help="time between decisions, s")


def run(args: argparse.Namespace) -> int:
    """Diagnose ``args.trace``; print the label changes."""
    import torch

    from thruster_fdd.core.diagnosis.offline import diagnose_trace
    from thruster_fdd.core.traces.files import read_traces

    torch.set_num_threads(1)
    if args.trace.is_dir() or not args.trace.is_file():
        raise BadInputError(f"{args.trace}: no such trace file")
    traces = read_traces([args.trace])
    if len(traces) > 1:
        print(f"note: {args.trace} holds {len(traces)} traces; using the first", file=sys.stderr)
    result = diagnose_trace(
        traces[0], args.models / "nominal", args.models / "classifier", hop_s=args.hop
    )
    if args.json is not None:
        write_text(args.json, json.dumps(result, indent=1) + "\n")
    windows = result["windows"]
    overall = result["overall"]
    print(
        f"{args.trace}: {overall['label']} (confidence {overall['confidence']:.2f}) over "
        f"{len(windows)} window(s)"
    )
    changes = [w for i, w in enumerate(windows) if i == 0 or w["label"] != windows[i - 1]["label"]]
    for w in changes:
        print(f"  from {w['t_end']:8.1f} s: {w['label']}")
    return EXIT_OK
