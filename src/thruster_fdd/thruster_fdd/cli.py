"""The ``thruster-fdd`` command: simulate, train, evaluate, diagnose, discrepancy, replay, up, ...

Every subcommand has ``--help``; exit code 0 on success, 2 on bad input with a one-line reason.
Subcommands whose capability is not built yet say which issue brings them and exit 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from thruster_fdd.core.data import CLASS_NAMES

EXIT_OK = 0
EXIT_BAD_INPUT = 2

# Subcommands whose capability a later issue brings; running them says so and exits 2.
PENDING: dict[str, str] = {
    "train": "issue 4 (nominal model) and issue 5 (classifier)",
    "evaluate": "issue 4 (Table 2) and issue 5 (Table 3)",
    "diagnose": "issue 5 (diagnosis)",
    "discrepancy": "issue 7 (discrepancy workflow)",
    "replay": "issue 6 (MCAP replay)",
    "record": "issue 6 (MCAP recorder)",
}


class UsageError(Exception):
    """Bad command-line input: printed as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line with a pointer to ``--help``."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _positive_float(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="write simulated thruster traces (CSV or MCAP)",
        description=(
            "Run the physics simulator of one thruster and write its telemetry as a trace CSV "
            "or an MCAP recording (topic /thruster/<id>/esc/telemetry). The simulator "
            "configuration is a preset or a YAML file (docs/simulator.md)."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    src = p.add_mutually_exclusive_group()
    src.add_argument("--preset", default="t100", help="simulator preset: t100 or t200")
    src.add_argument("--config", type=Path, help="simulator configuration YAML (overrides preset)")
    p.add_argument("--condition", default="nominal_15v", choices=CLASS_NAMES, help="condition")
    p.add_argument(
        "--voltage", type=_positive_float, help="supply voltage in V (default: the condition's)"
    )
    p.add_argument(
        "--fault-at",
        type=float,
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
    p.add_argument("--duration", type=_positive_float, default=60.0, help="duration in s")
    p.add_argument("--rate", type=_positive_float, default=10.0, help="sample rate in Hz")
    p.add_argument("--seed", type=int, default=0, help="seed: noise and unit-to-unit spread")
    p.add_argument("--thruster-id", default="t0", help="thruster id written with the trace")
    p.add_argument("--out", type=Path, required=True, help="output file, .csv or .mcap")
    p.set_defaults(func=_run_simulate)


def _add_train(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train the nominal model or the classifier from traces",
        description="Train and export a model from trace CSV / MCAP files or folders of them.",
    )
    what = p.add_subparsers(dest="what", metavar="{nominal,classifier}", required=True)
    n = what.add_parser("nominal", help="train and export the nominal NARX model")
    n.add_argument("--data", nargs="+", type=Path, required=True, metavar="TRACE")
    n.add_argument("--out", type=Path, default=Path("models/nominal"), metavar="DIR")
    n.add_argument("--seed", type=int, default=0)
    c = what.add_parser("classifier", help="train and export the fault classifier")
    c.add_argument("--data", nargs="+", type=Path, required=True, metavar="TRACE")
    c.add_argument("--nominal", type=Path, default=Path("models/nominal"), metavar="DIR")
    c.add_argument("--out", type=Path, default=Path("models/classifier"), metavar="DIR")
    c.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_pending("train"))


def _add_evaluate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help="evaluate models: the paper's Table 2 (nominal) and Table 3 (classifier)",
        description="Evaluate models on given data; writes Markdown, JSON and PNG.",
    )
    p.add_argument("target", choices=["nominal", "classifier"])
    p.add_argument("--model", type=Path, metavar="DIR")
    p.add_argument("--data", nargs="+", type=Path, metavar="TRACE")
    p.add_argument("--json", type=Path, metavar="OUT")
    p.set_defaults(func=_pending("evaluate"))


def _add_diagnose(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="offline diagnosis of a trace file (per window and overall, JSON)",
        description="Diagnose a trace CSV / MCAP file with the exported models.",
    )
    p.add_argument("trace", type=Path, metavar="TRACE")
    p.add_argument("--models", type=Path, default=Path("models"), metavar="DIR")
    p.add_argument("--json", type=Path, metavar="OUT")
    p.set_defaults(func=_pending("diagnose"))


def _add_discrepancy(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "discrepancy",
        help="name the physical effects the simulator misses against a measured trace",
        description="Compare the simulator with a measured trace and add the missing effects.",
    )
    p.add_argument("--measured", type=Path, required=True, metavar="TRACE")
    p.add_argument("--start", required=True, metavar="{t100|t200|CONFIG}")
    p.add_argument("--drop", action="append", default=[], metavar="EFFECT")
    p.add_argument("--out", type=Path, required=True, metavar="DIR")
    p.set_defaults(func=_pending("discrepancy"))


def _add_replay(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay",
        help="play an MCAP recording through the running node set",
        description="Replay a recording's telemetry through the nodes and check their output.",
    )
    p.add_argument("bag", type=Path, metavar="BAG")
    p.add_argument(
        "--rate", type=_positive_float, help="rate factor (default: as fast as possible)"
    )
    p.set_defaults(func=_pending("replay"))


def _add_record(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "record",
        help="record every topic of the graph to MCAP",
        description="Record all discovered topics as raw CDR to MCAP files.",
    )
    p.add_argument("--out", type=Path, default=Path("recordings"), metavar="DIR")
    p.set_defaults(func=_pending("record"))


def _add_up(sub: argparse._SubParsersAction) -> None:
    from thruster_fdd import launcher

    launcher.add_arguments(
        sub.add_parser(
            "up",
            help="start the node set on simulated (default) or real serial thrusters",
            description=launcher.DESCRIPTION,
            formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        )
    )


def _add_emulate(sub: argparse._SubParsersAction) -> None:
    from thruster_fdd import launcher

    launcher.add_emulate_arguments(
        sub.add_parser(
            "emulate",
            help="serve a simulated thruster's serial bridge on a pseudo-terminal",
            description=launcher.EMULATE_DESCRIPTION,
            formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        )
    )


def _pending(name: str) -> Callable[[argparse.Namespace], int]:
    def run(args: argparse.Namespace) -> int:
        print(
            f"thruster-fdd {name}: not available yet; it comes with {PENDING[name]}",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT

    return run


def _run_simulate(args: argparse.Namespace) -> int:
    from thruster_fdd.core.scenario import run_scenario
    from thruster_fdd.core.trace_io import write_trace

    if args.out.suffix not in (".csv", ".mcap"):
        raise UsageError(f"--out must end in .csv or .mcap, got {args.out}")
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


def build_parser() -> argparse.ArgumentParser:
    """Build the ``thruster-fdd`` argument parser with every subcommand."""
    parser = _Parser(
        prog="thruster-fdd",
        description=(
            "Onboard soft-fault detection and diagnosis for AUV thrusters (ROS 2 Jazzy). "
            "Run 'thruster-fdd SUBCOMMAND --help' for each subcommand."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="SUBCOMMAND", required=True)
    for add in (
        _add_simulate,
        _add_train,
        _add_evaluate,
        _add_diagnose,
        _add_discrepancy,
        _add_replay,
        _add_up,
        _add_record,
        _add_emulate,
    ):
        add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``thruster-fdd``; returns the process exit code."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except (ValueError, UsageError, FileNotFoundError) as exc:
        print(f"thruster-fdd {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
