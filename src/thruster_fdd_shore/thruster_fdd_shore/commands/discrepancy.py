"""``thruster-fdd discrepancy``: name the effects the simulator misses against a measured trace."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.commands.common import EXIT_OK, check_output

NAME = "discrepancy"
HELP = "name the physical effects the simulator misses against a measured trace"
DESCRIPTION = (
    "Calibrate a simulator configuration to a measured trace (free-run simulation error), then "
    "select, by blocked cross-validation, the moves that explain what it misses: effects of the "
    "vocabulary added (dead_time, deadband, esc_lag, slew_rate_limit, coulomb_friction, "
    "viscous_friction, voltage_sag, current_limit), effects of the start removed (superfluous) "
    "and changes of its base (bounds widened, a second ESC stage, the other braking law, drive "
    "losses). A move is taken only when its held-out gain exceeds its uncertainty, where the "
    "effect acts, and beyond a generic smooth correction; what that correction still explains "
    "is reported as a structured rest. Writes DIR/report.json, DIR/model.yaml, DIR/report.md, "
    "DIR/details.json and PNG plots. Verdict: effects_found, nothing_missing, or unexplained. "
    "Exit 2 with one line on bad input. Method and measured accuracy: docs/discrepancy.md."
)


MAX_WORKERS = 64
"""Most worker processes (each holds a copy of the data and a compiled free run)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd discrepancy``."""
    p.add_argument("--measured", type=Path, required=True, metavar="TRACE",
                   help="measured trace: trace CSV or MCAP (first thruster)")  # fmt: skip
    p.add_argument("--start", required=True, metavar="{t100|t200|CONFIG}",
                   help="starting configuration: preset name or YAML file")  # fmt: skip
    p.add_argument("--drop", action="append", default=[], metavar="EFFECT",
                   help="remove this effect from the start (repeatable)")  # fmt: skip
    p.add_argument("--out", type=Path, required=True, metavar="DIR",
                   help="report folder: new, empty or an earlier report's (replaced whole, "
                   "only once every file is written)")  # fmt: skip
    p.add_argument("--workers", type=int, default=2,
                   help="processes for the moves' re-fits (1-64; default 2)")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress output")


def run(args: argparse.Namespace) -> int:
    """Run the workflow and write the report."""
    from thruster_fdd_shore.core.discrepancy.engine import run_workflow
    from thruster_fdd_shore.core.discrepancy.report import check_out_dir, summary, write_report
    from thruster_fdd_shore.core.sim.config import load_config
    from thruster_fdd_shore.core.traces.files import read_traces

    if args.measured.is_dir() or not args.measured.is_file():
        raise BadInputError(f"--measured {args.measured}: no such trace file")
    if not 1 <= args.workers <= MAX_WORKERS:
        raise BadInputError(f"--workers must be within 1..{MAX_WORKERS}, got {args.workers}")
    check_output(args.out, "--out", folder=True)
    check_out_dir(args.out)
    source = load_config(args.start)
    traces = read_traces([args.measured])
    if len(traces) > 1:
        print(f"note: {args.measured} holds {len(traces)} traces; using the first", file=sys.stderr)
    log = None if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    result, data = run_workflow(
        traces[0], source, args.drop, workers=args.workers, progress=not args.quiet, log=log
    )
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    report = write_report(result, data, args.out)
    print(summary(report, args.out))
    return EXIT_OK
