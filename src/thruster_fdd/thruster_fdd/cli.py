"""The ``thruster-fdd`` command: simulate, train, evaluate, diagnose, discrepancy, replay, up, ...

Every subcommand has ``--help``; exit code 0 on success, 2 on bad input with a one-line reason.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from thruster_fdd.core.labels import CLASS_NAMES

EXIT_OK = 0
EXIT_BAD_INPUT = 2


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
    n = what.add_parser(
        "nominal",
        help="train and export the nominal NARX model",
        description=(
            "Train the nominal NARX (inputs command, voltage; outputs rpm, current) on healthy "
            "traces and export it (model.pt2 + model_card.json). The last --validation-fraction "
            "of every trace gives the card's validation metrics, then the model is retrained on "
            "everything. Same data and --seed give the same weights (docs/nominal_model.md)."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    n.add_argument("--data", nargs="+", type=Path, required=True, metavar="TRACE")
    n.add_argument("--out", type=Path, default=Path("models/nominal"), metavar="DIR")
    n.add_argument("--seed", type=int, default=0, help="seed of initialisation and shuffling")
    n.add_argument(
        "--mode",
        choices=["parallel", "series-parallel"],
        default="parallel",
        help="NARX configuration the node uses for residuals (and trains for)",
    )
    n.add_argument("--validation-fraction", type=float, default=0.2, metavar="F")
    n.add_argument("--epochs", type=int, help="one-step epochs (default: the mode's default)")
    n.add_argument(
        "--finetune-epochs", type=int, help="free-run epochs, parallel (default: the mode's)"
    )
    n.set_defaults(func=_run_train_nominal)
    c = what.add_parser(
        "classifier",
        help="train and export the fault classifier",
        description=(
            "Train the window classifier (MLP on residual and signal features, calibrated, with "
            "an UNKNOWN answer) on labelled traces: the 'condition' column of a trace CSV or the "
            "labels of a recording; a trace whose label changes mid-run is used on both sides "
            "of the change. Residuals come from the exported nominal model --nominal, whose id "
            "the card records. Exports model.pt2 + model_card.json (docs/diagnosis.md)."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    c.add_argument("--data", nargs="+", type=Path, required=True, metavar="TRACE")
    c.add_argument("--nominal", type=Path, default=Path("models/nominal"), metavar="DIR")
    c.add_argument("--out", type=Path, default=Path("models/classifier"), metavar="DIR")
    c.add_argument("--seed", type=int, default=0, help="seed of initialisation")
    c.add_argument("--window", type=_positive_float, default=20.0, help="window length, s")
    c.add_argument("--epochs", type=int, default=400, help="training epochs (full batch)")
    c.set_defaults(func=_run_train_classifier)


def _record_training_files(out_dir: Path, sources: list[Path]) -> None:
    """Add each training file's name and SHA-256 to the exported card's ``extra``."""
    import json

    from thruster_fdd.core.traces.files import file_digests

    card_path = out_dir / "model_card.json"
    card = json.loads(card_path.read_text())
    card.setdefault("extra", {})["training_files"] = file_digests(sources)
    card_path.write_text(json.dumps(card, indent=2) + "\n")


def _run_train_classifier(args: argparse.Namespace) -> int:
    import torch

    from thruster_fdd.core.diagnosis.training import ClassifierConfig, train_classifier
    from thruster_fdd.core.traces.files import read_traces

    if args.epochs < 1:
        raise UsageError(f"--epochs must be >= 1, got {args.epochs}")
    torch.set_num_threads(1)
    traces = read_traces(args.data)
    config = ClassifierConfig(window_s=args.window, epochs=args.epochs)
    card = train_classifier(
        traces, args.nominal, args.out, seed=args.seed, config=config, progress=True
    )
    _record_training_files(args.out, args.data)
    m = card.training_metrics["heldout"]
    print(
        f"exported {card.model_id} to {args.out}: {len(traces)} trace(s), nominal model "
        f"{card.nominal_model_id}; held-out windows: balanced accuracy "
        f"{m['balanced_accuracy']:.4f}, ECE {m['ece']:.4f}"
    )
    return EXIT_OK


def _run_train_nominal(args: argparse.Namespace) -> int:
    import torch

    from thruster_fdd.core.nominal.training import default_config, train_nominal
    from thruster_fdd.core.traces.files import read_traces

    if not 0.0 <= args.validation_fraction < 1.0:
        raise UsageError(f"--validation-fraction must be in [0, 1), got {args.validation_fraction}")
    changes = {
        k: v for k, v in (("epochs", args.epochs), ("finetune_epochs", args.finetune_epochs))
        if v is not None
    }  # fmt: skip
    if any(v < 0 for v in changes.values()):
        raise UsageError("--epochs and --finetune-epochs must be >= 0")
    torch.set_num_threads(1)
    traces = read_traces(args.data)
    card = train_nominal(
        traces,
        args.out,
        seed=args.seed,
        config=default_config(args.mode, **changes),
        validation_fraction=args.validation_fraction,
        progress=True,
    )
    _record_training_files(args.out, args.data)
    m = card.training_metrics.get("validation", card.training_metrics["train"])
    print(
        f"exported {card.model_id} ({card.mode}) to {args.out}: {len(traces)} trace(s); "
        f"rpm r2 {m['rpm_r2']:.4f}, current r2 {m['current_r2']:.4f}"
    )
    return EXIT_OK


def _add_evaluate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help="evaluate models: the paper's Table 2 (nominal) and Table 3 (classifier)",
        description=(
            "evaluate nominal --model DIR --data TRACE... [--json OUT]: metrics of an exported "
            "nominal model on traces (free run by default). evaluate nominal without --model: "
            "the paper's Table 2 protocol on simulated data (train on the 0.01 Hz sine, test at "
            "0.01-0.04 Hz, repeated seeds; ours vs the paper vs SysIdentPy) written to --out as "
            "Markdown, JSON and PNG. evaluate classifier [--model DIR] [--nominal DIR] [--seed "
            "N]: the paper's Table 3 protocol (MLP and LSTM per sample on signals and on "
            "residuals, 3-fold time-series CV, separate test set) beside the exported window "
            "classifier on unseen simulated thrusters, fault-onset times and UNKNOWN checks, "
            "written to --out as table3.md, table3.json and confusion-matrix PNGs."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("target", choices=["nominal", "classifier"])
    p.add_argument("--model", type=Path, metavar="DIR")
    p.add_argument("--data", nargs="+", type=Path, metavar="TRACE")
    p.add_argument("--json", type=Path, metavar="OUT")
    p.add_argument(
        "--mode",
        choices=["parallel", "series-parallel"],
        default="parallel",
        help="with --model: NARX configuration to evaluate",
    )
    p.add_argument(
        "--out",
        type=Path,
        metavar="DIR",
        help="output folder (default out/table2 for nominal, out/table3 for classifier)",
    )
    p.add_argument(
        "--nominal",
        type=Path,
        default=Path("models/nominal"),
        metavar="DIR",
        help="classifier: the nominal model that makes the residuals",
    )
    p.add_argument("--seed", type=int, default=0, help="classifier: seed (shifts unseen units)")
    p.add_argument("--seeds", type=int, default=3, help="Table 2: repeated runs (seeds 0..N-1)")
    p.add_argument("--rate", type=float, default=10.0, help="Table 2: sample rate, Hz")
    p.add_argument("--train-samples", type=int, default=2000, help="Table 2")
    p.add_argument("--test-samples", type=int, default=1000, help="Table 2")
    p.add_argument("--epochs", type=int, help="Table 2: one-step epochs (default: training's)")
    p.add_argument("--no-sysidentpy", action="store_true", help="Table 2: skip the peer")
    p.add_argument("--no-plots", action="store_true", help="Table 2: skip the figures")
    p.set_defaults(func=_run_evaluate)


def _run_evaluate(args: argparse.Namespace) -> int:
    if args.target == "classifier":
        return _run_evaluate_classifier(args)
    if args.out is None:
        args.out = Path("out/table2")
    import json
    from dataclasses import replace

    import torch

    from thruster_fdd.core.nominal.evaluation import (
        ProtocolConfig,
        evaluate_model_on_traces,
        plot_table2_predictions,
        run_table2,
        table2_markdown,
    )

    torch.set_num_threads(1)
    if args.model is not None:
        from thruster_fdd.core.nominal.runtime import NominalModel
        from thruster_fdd.core.traces.files import read_traces

        if not args.data:
            raise UsageError("evaluate nominal --model needs --data TRACE...")
        result = evaluate_model_on_traces(
            NominalModel.load(args.model), read_traces(args.data), args.mode
        )
        text = json.dumps(result, indent=2)
        if args.json is not None:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(text + "\n")
        print(text)
        return EXIT_OK
    if args.seeds < 1 or args.train_samples < 100 or args.test_samples < 100:
        raise UsageError("need --seeds >= 1 and --train-samples, --test-samples >= 100")
    cfg = ProtocolConfig(
        rate_hz=args.rate,
        train_samples=args.train_samples,
        test_samples=args.test_samples,
        seeds=tuple(range(args.seeds)),
        sysidentpy=not args.no_sysidentpy,
    )
    if args.epochs is not None:
        cfg = replace(cfg, train=replace(cfg.train, epochs=args.epochs))
    scores = run_table2(cfg, progress=True)
    args.out.mkdir(parents=True, exist_ok=True)
    table = table2_markdown(scores, cfg)
    (args.out / "table2.md").write_text(table)
    rows = [dict(vars(s), r2=s.r2) for s in scores]
    json_path = args.json if args.json is not None else args.out / "table2.json"
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(rows, indent=1) + "\n")
    if not args.no_plots:
        plot_table2_predictions(cfg, args.out)
    print(table)
    print(f"wrote {args.out / 'table2.md'}, {json_path}")
    return EXIT_OK


def _run_evaluate_classifier(args: argparse.Namespace) -> int:
    import torch

    from thruster_fdd.core.diagnosis.evaluation import run_evaluation
    from thruster_fdd.core.diagnosis.table3 import table3_markdown

    torch.set_num_threads(1)
    out = args.out if args.out is not None else Path("out/table3")
    model = args.model if args.model is not None else Path("models/classifier")
    result = run_evaluation(args.nominal, model, out, seed=args.seed, progress=True)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text((out / "table3.json").read_text())
    print(table3_markdown(result))
    print(f"wrote {out / 'table3.md'}, {out / 'table3.json'} and confusion PNGs in {out}")
    return EXIT_OK


def _add_diagnose(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="offline diagnosis of a trace file (per window and overall, JSON)",
        description=(
            "Diagnose a trace CSV / MCAP file with the exported models (DIR/nominal and "
            "DIR/classifier), through the same residual and window code as the nodes: one "
            "decision per --hop seconds over the classifier's window, and an overall label. "
            "JSON: {overall: {label, confidence}, windows: [{t_start, t_end, label, "
            "probabilities}]}."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("trace", type=Path, metavar="TRACE")
    p.add_argument("--models", type=Path, default=Path("models"), metavar="DIR")
    p.add_argument("--json", type=Path, metavar="OUT")
    p.add_argument("--hop", type=_positive_float, default=1.0, help="time between decisions, s")
    p.set_defaults(func=_run_diagnose)


def _run_diagnose(args: argparse.Namespace) -> int:
    import json

    import torch

    from thruster_fdd.core.diagnosis.offline import diagnose_trace
    from thruster_fdd.core.traces.files import read_traces

    torch.set_num_threads(1)
    if args.trace.is_dir() or not args.trace.is_file():
        raise UsageError(f"{args.trace}: no such trace file")
    traces = read_traces([args.trace])
    if len(traces) > 1:
        print(f"note: {args.trace} holds {len(traces)} traces; using the first", file=sys.stderr)
    result = diagnose_trace(
        traces[0], args.models / "nominal", args.models / "classifier", hop_s=args.hop
    )
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")
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


def _add_discrepancy(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "discrepancy",
        help="name the physical effects the simulator misses against a measured trace",
        description=(
            "Calibrate a simulator configuration to a measured trace (free-run simulation "
            "error), locate where it disagrees, name the missing effects of the effect "
            "vocabulary (dead_time, deadband, esc_lag, slew_rate_limit, coulomb_friction, "
            "viscous_friction, voltage_sag, current_limit) and write DIR/report.json, "
            "DIR/model.yaml, DIR/report.md and PNG plots (docs/discrepancy.md)."
        ),
    )
    p.add_argument("--measured", type=Path, required=True, metavar="TRACE",
                   help="measured trace: trace CSV or MCAP (first thruster)")  # fmt: skip
    p.add_argument("--start", required=True, metavar="{t100|t200|CONFIG}",
                   help="starting configuration: preset name or YAML file")  # fmt: skip
    p.add_argument("--drop", action="append", default=[], metavar="EFFECT",
                   help="remove this effect from the start (repeatable)")  # fmt: skip
    p.add_argument("--out", type=Path, required=True, metavar="DIR")
    p.add_argument("--workers", type=int, default=2, help="processes for candidate re-fits")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    def run(args: argparse.Namespace) -> int:
        from thruster_fdd.core.discrepancy.report import write_report
        from thruster_fdd.core.discrepancy.search import run_workflow as run_discrepancy
        from thruster_fdd.core.sim.config import load_config
        from thruster_fdd.core.traces.files import read_traces

        if args.measured.is_dir() or not args.measured.is_file():
            raise UsageError(f"--measured {args.measured}: no such trace file")
        if args.workers < 1:
            raise UsageError(f"--workers must be >= 1, got {args.workers}")
        source = load_config(args.start)
        traces = read_traces([args.measured])
        if len(traces) > 1:
            print(f"note: {args.measured} holds {len(traces)} traces; using the first",
                  file=sys.stderr)  # fmt: skip
        log = None if args.quiet else (lambda msg: print(msg, file=sys.stderr))
        result, data = run_discrepancy(
            traces[0], source, args.drop, workers=args.workers, progress=not args.quiet, log=log
        )
        for warning in result.warnings:
            print(f"warning: {warning}", file=sys.stderr)
        write_report(result, data, args.out)
        named = ", ".join(result.added) or "none"
        print(f"{result.verdict}: missing {named}; report in {args.out}")
        return EXIT_OK

    p.set_defaults(func=run)


def _add_replay(sub: argparse._SubParsersAction) -> None:
    from thruster_fdd import replay

    replay.add_arguments(
        sub.add_parser(
            "replay",
            help="play an MCAP recording through the model nodes and check the diagnoses",
            description=replay.DESCRIPTION,
            formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        )
    )


def _add_record(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "record",
        help="record every topic of the graph to MCAP",
        description=(
            "Run the recorder node in the foreground: every discovered topic, as raw CDR, into "
            "size/duration-split MCAP files (rosbag2 layout) until Ctrl-C. More settings: the "
            "recorder's ROS parameters (README)."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", type=Path, default=Path("recordings"), metavar="DIR")
    p.add_argument("--max-file-mb", type=_positive_float, default=256.0, help="split size, MiB")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    p.add_argument("--vehicle", default="sim-auv", help="vehicle name for the metadata")
    p.set_defaults(func=_run_record)


def _run_record(args: argparse.Namespace) -> int:
    from thruster_fdd.nodes import recorder

    recorder.main(
        [
            "--ros-args",
            "-p",
            f"output_dir:={args.out}",
            "-p",
            f"max_file_mb:={args.max_file_mb}",
            "-p",
            f"compression:={args.compression}",
            "-p",
            f"vehicle:={args.vehicle}",
        ]
    )
    return EXIT_OK


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


def _add_reload(sub: argparse._SubParsersAction) -> None:
    from thruster_fdd import reload

    reload.add_arguments(
        sub.add_parser(
            "reload",
            help="load newly exported models into running nodes without a restart",
            description=reload.DESCRIPTION,
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


def _run_simulate(args: argparse.Namespace) -> int:
    from thruster_fdd.core.sim.scenario import run_scenario
    from thruster_fdd.core.traces.files import write_trace

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
        _add_reload,
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
