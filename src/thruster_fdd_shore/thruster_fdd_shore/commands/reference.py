"""``thruster-fdd reference``: export a thruster type's reference load curves for the health
node."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from thruster_fdd_shore.commands.common import EXIT_OK, check_output, positive_float

NAME = "reference"
HELP = "export a thruster type's reference load curves for the health node"
DESCRIPTION = (
    "Solve a thruster type's simulator configuration at steady state for every fault family "
    "(blades lost 0..2, fouling 0..2), severity and supply-voltage bin, and export the power "
    "and thrust curves the health node's effectiveness estimate compares telemetry with, as a "
    "folder checked by digest (model_card.json, weights.npz). The vehicle only reads it "
    "(health parameter 'reference'; default: the models folder's reference/). About 1.3 s of "
    "CPU per voltage bin."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd reference``."""
    p.add_argument("--preset", default="t100", help="simulator preset or configuration YAML")
    p.add_argument("--out", type=Path, required=True, help="reference folder to write")
    p.add_argument(
        "--min-voltage", type=positive_float, default=10.0, help="lowest supply bin, V (>= 6)"
    )
    p.add_argument(
        "--max-voltage", type=positive_float, default=20.0, help="highest supply bin, V (<= 30)"
    )
    p.add_argument("--force", action="store_true", help="replace an existing folder")


def run(args: argparse.Namespace) -> int:
    """Compute and write the reference folder."""
    from thruster_fdd.core.errors import BadInputError
    from thruster_fdd_shore.core.reference import export_reference, voltage_grid
    from thruster_fdd_shore.core.sim.config import load_config

    check_output(args.out, "--out", folder=True)
    if args.out.exists() and any(args.out.iterdir()) and not args.force:
        raise BadInputError(f"--out {args.out}: exists (--force replaces it)")
    voltages = voltage_grid(args.min_voltage, args.max_voltage)
    config = load_config(args.preset)
    name = args.preset if isinstance(args.preset, str) and "/" not in args.preset else "custom"
    name = Path(name).stem

    def progress(done: int, total: int) -> None:
        bar = "#" * (30 * done // total)
        print(f"\r[reference] {bar:<30} {done}/{total} bins", end="", file=sys.stderr)

    card = export_reference(config, name, args.out, voltages, progress)
    print(file=sys.stderr)
    print(f"{card.model_id}: {len(voltages)} bins {voltages[0]:g}-{voltages[-1]:g} V -> {args.out}")
    return EXIT_OK
