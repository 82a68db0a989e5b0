"""``thruster-fdd simulate``: simulated thruster traces as trace CSV or MCAP."""

from __future__ import annotations

import argparse
from pathlib import Path

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES
from thruster_fdd_shore.commands.common import (
    EXIT_OK,
    check_output,
    finite_float,
    non_negative_int,
    positive_float,
)

NAME = "simulate"
HELP = "write simulated thruster traces (CSV or MCAP)"
DESCRIPTION = (
    "Run the physics simulator of one thruster and write its telemetry as a trace CSV or an MCAP "
    "recording (topic /thruster/<id>/esc/telemetry). The simulator configuration is a preset or "
    "a YAML file (docs/simulator.md). At most 10 million samples (--duration x --rate)."
)


MAX_SAMPLES = 10_000_000
"""Most samples one run writes (28 h at 100 Hz; about 1 GB of CSV): a bound on memory."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd simulate``."""
    src = p.add_mutually_exclusive_group()
    src.add_argument("--preset", default="t100", help="simulator preset: t100 or t200")
    src.add_argument("--config", type=Path, help="simulator configuration YAML (overrides preset)")
    p.add_argument("--condition", default="nominal_15v", choices=CLASS_NAMES, help="condition")
    p.add_argument(
        "--voltage", type=positive_float, help="supply voltage in V (default: the condition's)"
    )
    p.add_argument(
        "--fault-at",
        type=finite_float,
        metavar="S",
        help="switch to --fault-condition at this time in s (fault injection mid-run)",
    )
    p.add_argument("--fault-condition", choices=CLASS_NAMES, help="condition after --fault-at")
    cmd = p.add_mutually_exclusive_group()
    cmd.add_argument(
        "--signal",
        default="steps",
        help="command signal: steps | sine:F (F in Hz) | chirp | multilevel | mission",
    )
    cmd.add_argument(
        "--command-csv",
        type=Path,
        help="drive the simulator with this command history (CSV columns t, command)",
    )
    p.add_argument("--duration", type=positive_float, default=60.0, help="duration in s")
    p.add_argument("--rate", type=positive_float, default=10.0, help="sample rate in Hz")
    p.add_argument(
        "--seed", type=non_negative_int, default=0, help="seed: noise and unit-to-unit spread"
    )
    p.add_argument("--thruster-id", default="t0", help="thruster id written with the trace")
    p.add_argument("--out", type=Path, required=True, help="output file, .csv or .mcap")


def run(args: argparse.Namespace) -> int:
    """Simulate and write the trace."""
    from thruster_fdd_shore.core.sim.scenario import run_scenario
    from thruster_fdd_shore.core.traces.files import write_trace

    if args.out.suffix not in (".csv", ".mcap"):
        raise BadInputError(f"--out must end in .csv or .mcap, got {args.out}")
    check_output(args.out, "--out")
    samples = args.duration * args.rate
    if samples > MAX_SAMPLES:
        raise BadInputError(
            f"--duration {args.duration:g} s at --rate {args.rate:g} Hz is {samples:.3g} samples; "
            f"at most {MAX_SAMPLES:.0e} per run (split it into several runs)"
        )
    if args.fault_at is not None and not 0.0 <= args.fault_at < args.duration:
        raise BadInputError(
            f"--fault-at {args.fault_at:g} s must lie within the run, 0..{args.duration:g} s"
        )
    if args.command_csv is not None and not args.command_csv.is_file():
        raise BadInputError(f"--command-csv {args.command_csv}: no such file")
    if not args.thruster_id.isidentifier():
        raise BadInputError(f"--thruster-id {args.thruster_id!r} must be a ROS name token like t0")
    trace = run_scenario(
        args.config if args.config is not None else args.preset,
        args.condition,
        signal=args.signal,
        command_csv=args.command_csv,
        duration_s=args.duration,
        rate_hz=args.rate,
        voltage=args.voltage,
        seed=args.seed,
        thruster_id=args.thruster_id,
        fault_at_s=args.fault_at,
        fault_condition=args.fault_condition,
    )
    write_trace(trace, args.out)
    span = trace.t[-1] - trace.t[0]
    print(f"wrote {len(trace)} samples ({span:.1f} s, thruster {trace.thruster_id}) to {args.out}")
    return EXIT_OK
