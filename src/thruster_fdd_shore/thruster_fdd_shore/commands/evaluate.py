"""``thruster-fdd evaluate nominal|classifier``: the paper's Table 2 and Table 3, and beyond."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.commands.common import (
    EXIT_OK,
    MODELS_HELP,
    check_output,
    model_folder,
    non_negative_int,
    positive_float,
)

NAME = "evaluate"
HELP = "evaluate models: the paper's Table 2 (nominal) and Table 3 (classifier)"
DESCRIPTION = (
    "evaluate nominal: an exported nominal model on traces, or the paper's Table 2. evaluate "
    "classifier: the paper's Table 3 beside the exported window classifier. Each target has its "
    "own options: `thruster-fdd evaluate nominal --help`."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd evaluate`` and its two targets, each with its own."""
    what = p.add_subparsers(dest="target", metavar="{nominal,classifier}", required=True)
    n = what.add_parser(
        "nominal",
        help="an exported nominal model on traces (--model), or the paper's Table 2",
        description=(
            "With --model DIR --data TRACE...: metrics of an exported nominal model on traces "
            "(free run by default; JSON with --json). Without --model: the paper's Table 2 "
            "protocol on simulated data (train on the 0.01 Hz sine, test at 0.01-0.04 Hz, "
            "repeated seeds; ours vs the paper vs SysIdentPy) written to --out as Markdown, JSON "
            "and PNG."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    n.add_argument("--model", type=Path, metavar="DIR", help="exported nominal model folder")
    n.add_argument(
        "--data", nargs="+", type=Path, metavar="TRACE", help="with --model: traces to score"
    )
    n.add_argument("--json", type=Path, metavar="OUT", help="write the metrics as JSON here")
    n.add_argument(
        "--mode",
        choices=["parallel", "series-parallel"],
        default="parallel",
        help="with --model: NARX configuration to evaluate (parallel: free run)",
    )
    n.add_argument(
        "--out", type=Path, default=Path("out/table2"), metavar="DIR", help="Table 2 folder"
    )
    n.add_argument("--seeds", type=int, default=3, help="Table 2: repeated runs (seeds 0..N-1)")
    n.add_argument("--rate", type=positive_float, default=10.0, help="Table 2: sample rate, Hz")
    n.add_argument(
        "--train-samples", type=int, default=2000, help="Table 2: training samples, 100..1000000"
    )
    n.add_argument(
        "--test-samples", type=int, default=1000, help="Table 2: test samples, 100..1000000"
    )
    n.add_argument(
        "--epochs", type=non_negative_int, help="Table 2: one-step epochs (default: training's)"
    )
    n.add_argument("--no-sysidentpy", action="store_true", help="Table 2: skip the peer")
    n.add_argument("--no-plots", action="store_true", help="Table 2: skip the figures")
    c = what.add_parser(
        "classifier",
        help="the paper's Table 3 beside the exported window classifier",
        description=(
            "The paper's Table 3 protocol (MLP and LSTM per sample on signals and on residuals, "
            "3-fold time-series CV, separate test set) beside the exported window classifier on "
            "unseen simulated thrusters, fault-onset times and UNKNOWN checks, written to --out "
            "as table3.md, table3.json and confusion-matrix PNGs."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    c.add_argument(
        "--model",
        type=Path,
        metavar="DIR",
        help=f"exported classifier (<models>/classifier; {MODELS_HELP})",
    )
    c.add_argument(
        "--nominal",
        type=Path,
        metavar="DIR",
        help=f"the nominal model that makes the residuals (<models>/nominal; {MODELS_HELP})",
    )
    c.add_argument("--seed", type=non_negative_int, default=0, help="seed (shifts unseen units)")
    c.add_argument("--out", type=Path, default=Path("out/table3"), metavar="DIR", help="folder")
    c.add_argument("--json", type=Path, metavar="OUT", help="also copy table3.json here")


def run(args: argparse.Namespace) -> int:
    """Evaluate ``args.target``."""
    import torch

    if args.json is not None:
        check_output(args.json, "--json")
    if args.out is not None:
        check_output(args.out, "--out", folder=True)
    torch.set_num_threads(1)
    if args.target == "classifier":
        return _classifier(args)
    if args.model is not None:
        return _nominal_model(args)
    return _table2(args)


def _nominal_model(args: argparse.Namespace) -> int:
    from thruster_fdd.core.nominal.runtime import NominalModel
    from thruster_fdd_shore.core.nominal.evaluation import evaluate_model_on_traces
    from thruster_fdd_shore.core.traces.files import read_traces

    if not args.data:
        raise BadInputError("evaluate nominal --model needs --data TRACE...")
    result = evaluate_model_on_traces(
        NominalModel.load(args.model), read_traces(args.data), args.mode
    )
    text = json.dumps(result, indent=2)
    if args.json is not None:
        write_text(args.json, text + "\n")
    print(text)
    return EXIT_OK


def _table2(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from thruster_fdd_shore.core.nominal import evaluation as ev

    out = args.out
    if not (
        1 <= args.seeds <= 100
        and 100 <= args.train_samples <= 1_000_000
        and 100 <= args.test_samples <= 1_000_000
    ):
        raise BadInputError(
            "need --seeds within 1..100 and --train-samples, --test-samples within 100..1000000"
        )
    cfg = ev.ProtocolConfig(
        rate_hz=args.rate,
        train_samples=args.train_samples,
        test_samples=args.test_samples,
        seeds=tuple(range(args.seeds)),
        sysidentpy=not args.no_sysidentpy,
    )
    if args.epochs is not None:
        cfg = replace(cfg, train=replace(cfg.train, epochs=args.epochs))
    scores = ev.run_table2(cfg, progress=True)
    table = ev.table2_markdown(scores, cfg)
    write_text(out / "table2.md", table)
    rows = [dict(vars(s), r2=s.r2) for s in scores]
    json_path = args.json if args.json is not None else out / "table2.json"
    write_text(json_path, json.dumps(rows, indent=1) + "\n")
    if not args.no_plots:
        ev.plot_table2_predictions(cfg, out)
    print(table)
    print(f"wrote {out / 'table2.md'}, {json_path}")
    return EXIT_OK


def _classifier(args: argparse.Namespace) -> int:
    from thruster_fdd_shore.core.diagnosis.evaluation import run_evaluation
    from thruster_fdd_shore.core.diagnosis.table3 import table3_markdown

    out = args.out
    model = model_folder(args.model, "classifier")
    nominal = model_folder(args.nominal, "nominal")
    result = run_evaluation(nominal, model, out, seed=args.seed, progress=True)
    if args.json is not None:
        write_text(args.json, (out / "table3.json").read_text())
    print(table3_markdown(result))
    print(f"wrote {out / 'table3.md'}, {out / 'table3.json'} and confusion PNGs in {out}")
    return EXIT_OK
