"""``thruster-fdd train nominal|classifier``: train and export a model from traces."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.commands.common import (
    EXIT_OK,
    MODELS_HELP,
    check_output,
    model_folder,
    non_negative_int,
    positive_float,
    refuse_shipped,
)

if TYPE_CHECKING:
    from thruster_fdd.core.traces.data import Trace

NAME = "train"
HELP = "train the nominal model or the classifier from traces"
DESCRIPTION = "Train and export a model from trace CSV / MCAP files or folders of them."


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd train`` and its two targets."""
    what = p.add_subparsers(dest="what", metavar="{nominal,classifier}", required=True)
    n = what.add_parser(
        "nominal",
        help="train and export the nominal NARX model",
        description=(
            "Train the nominal NARX (inputs command, voltage; outputs rpm, current) on healthy "
            "traces and export it (model_card.json, weights.npz, model.pt2). The last "
            "--validation-fraction of every trace gives the card's validation metrics, then the "
            "model is retrained on everything. Same data and --seed give the same weights "
            "(docs/nominal_model.md). An existing --out folder is replaced only by a complete, "
            "checked export."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    n.add_argument(
        "--data",
        nargs="+",
        type=Path,
        required=True,
        metavar="TRACE",
        help="healthy traces: CSV / MCAP files, bag folders or folders of them",
    )
    n.add_argument(
        "--out",
        type=Path,
        metavar="DIR",
        help=f"export folder (<models>/nominal; {MODELS_HELP}); the shipped one needs --force",
    )
    n.add_argument(
        "--force", action="store_true", help="replace the models folder's exported model"
    )
    n.add_argument(
        "--seed", type=non_negative_int, default=0, help="seed of initialisation and shuffling"
    )
    n.add_argument(
        "--mode",
        choices=["parallel", "series-parallel"],
        default="series-parallel",
        help="NARX configuration the node uses for residuals (and trains for); the shipped "
        "model's and evaluate's",
    )
    n.add_argument(
        "--validation-fraction",
        type=float,
        default=0.2,
        metavar="F",
        help="last fraction of every trace held out for the card's validation metrics, [0, 1)",
    )
    n.add_argument(
        "--epochs", type=non_negative_int, help="one-step epochs (default: the mode's default)"
    )
    n.add_argument(
        "--finetune-epochs",
        type=non_negative_int,
        help="free-run epochs, parallel (default: the mode's)",
    )
    c = what.add_parser(
        "classifier",
        help="train and export the fault classifier",
        description=(
            "Train the window classifier (MLP on residual and signal features, calibrated, with "
            "an UNKNOWN answer) on labelled traces: the 'condition' column of a trace CSV or the "
            "labels of a recording; a trace whose label changes mid-run is used on both sides "
            "of the change. Residuals come from the exported nominal model --nominal, whose id "
            "the card records. Exports model_card.json, weights.npz and model.pt2 "
            "(docs/diagnosis.md)."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    c.add_argument(
        "--data",
        nargs="+",
        type=Path,
        required=True,
        metavar="TRACE",
        help="labelled traces: CSV / MCAP files, bag folders or folders of them",
    )
    c.add_argument(
        "--nominal",
        type=Path,
        metavar="DIR",
        help=f"exported nominal model making the residuals (<models>/nominal; {MODELS_HELP})",
    )
    c.add_argument(
        "--out",
        type=Path,
        metavar="DIR",
        help=f"export folder (<models>/classifier; {MODELS_HELP}); the shipped one needs --force",
    )
    c.add_argument(
        "--force", action="store_true", help="replace the models folder's exported model"
    )
    c.add_argument("--seed", type=non_negative_int, default=0, help="seed of initialisation")
    c.add_argument("--window", type=positive_float, default=20.0, help="window length, s")
    c.add_argument("--epochs", type=int, default=400, help="training epochs (full batch)")
    c.add_argument(
        "--min-band-accuracy",
        type=float,
        default=0.95,
        metavar="P",
        help="accuracy (0..1) with which held-out units must be told healthy from faulty in a "
        "0.05 band of mean |command| for windows there to give evidence",
    )


MIN_TRACE_S = 10.0
"""Shortest trace ``train nominal`` takes, s (the lookback is 2 s, then validation and
training parts of each trace)."""


MIN_WINDOW_SAMPLES = 4
"""Fewest nominal-model samples in a classifier window."""


MAX_WINDOW_S = 600.0
"""Longest classifier window, s."""


def _read_long_traces(sources: list[Path]) -> list[Trace]:
    """The traces of ``sources``; BadInputError naming a file with one shorter than
    ``MIN_TRACE_S``."""
    from thruster_fdd_shore.core.traces.files import read_traces, trace_files

    traces = []
    for file in trace_files(sources):
        for trace in read_traces([file]):
            span = float(trace.t[-1] - trace.t[0])
            if span < MIN_TRACE_S:
                raise BadInputError(
                    f"{file}: a trace of {span:g} s; training needs at least {MIN_TRACE_S:g} s"
                )
            traces.append(trace)
    return traces


def run(args: argparse.Namespace) -> int:
    """Train and export the model ``args.what``."""
    import torch

    from thruster_fdd_shore.core.traces.files import file_digests, read_traces

    args.out = model_folder(args.out, args.what)
    if args.what == "classifier":
        args.nominal = model_folder(args.nominal, "nominal")
    check_output(args.out, "--out", folder=True)
    refuse_shipped(args.out, args.force)
    if args.out.resolve() in {Path(d).resolve() for d in args.data}:
        raise BadInputError(f"--out {args.out} is also a --data folder; it would be replaced")
    torch.set_num_threads(1)
    if args.what == "nominal":
        from thruster_fdd_shore.core.nominal.training import default_config, train_nominal

        if not 0.0 <= args.validation_fraction < 1.0:
            raise BadInputError(
                f"--validation-fraction must be in [0, 1), got {args.validation_fraction}"
            )
        changes = {
            k: v for k, v in (("epochs", args.epochs), ("finetune_epochs", args.finetune_epochs))
            if v is not None
        }  # fmt: skip
        traces = _read_long_traces(args.data)
        card = train_nominal(
            traces,
            args.out,
            seed=args.seed,
            config=default_config(args.mode, **changes),
            validation_fraction=args.validation_fraction,
            progress=True,
            extra={"training_files": file_digests(args.data)},
        )
        m = card.training_metrics.get("validation", card.training_metrics["train"])
        print(
            f"exported {card.model_id} ({card.mode}) to {args.out}: {len(traces)} trace(s); "
            f"rpm r2 {m['rpm_r2']:.4f}, current r2 {m['current_r2']:.4f}"
        )
        return EXIT_OK
    from thruster_fdd.core.artifact import check_files
    from thruster_fdd.core.nominal.card import read_nominal_card
    from thruster_fdd_shore.core.diagnosis.training import ClassifierConfig, train_classifier

    if args.out.resolve() == args.nominal.resolve():
        raise BadInputError(f"--out {args.out} is the --nominal model; it would be replaced")
    check_files(args.nominal, read_nominal_card(args.nominal))
    if args.epochs < 1:
        raise BadInputError(f"--epochs must be >= 1, got {args.epochs}")
    sample_time_s = read_nominal_card(args.nominal).sample_time_s
    if not MIN_WINDOW_SAMPLES * sample_time_s <= args.window <= MAX_WINDOW_S:
        raise BadInputError(
            f"--window must be within {MIN_WINDOW_SAMPLES * sample_time_s:g}..{MAX_WINDOW_S:g} s "
            f"({MIN_WINDOW_SAMPLES} samples of the nominal model at least), got {args.window:g}"
        )
    if not 0.5 <= args.min_band_accuracy <= 1.0:
        raise BadInputError(f"--min-band-accuracy must be in 0.5..1, got {args.min_band_accuracy}")
    traces = read_traces(args.data)
    config = ClassifierConfig(
        window_s=args.window, epochs=args.epochs, min_band_accuracy=args.min_band_accuracy
    )
    card = train_classifier(
        traces,
        args.nominal,
        args.out,
        seed=args.seed,
        config=config,
        progress=True,
        extra={"training_files": file_digests(args.data)},
    )
    m = card.training_metrics["heldout"]
    print(
        f"exported {card.model_id} to {args.out}: {len(traces)} trace(s), nominal model "
        f"{card.nominal_model_id}; held-out windows: balanced accuracy "
        f"{m['balanced_accuracy']:.4f}, ECE {m['ece']:.4f}"
    )
    cal = card.calibration
    units = ", ".join(cal["units"]) or "a time split of the traces"
    print(f"calibrated on {cal['windows']} held-out windows of {units}: ECE {cal['ece']:.4f}")
    print(f"training region (1st-99th percentile; threshold {card.coverage['threshold']:.2f}):")
    for name, (lo, hi) in card.coverage["summary"].items():
        print(f"  {name:<17} {lo:8.3f} .. {hi:8.3f}")
    floor = card.coverage["evidence_floor"]
    need = floor["min_accuracy"]
    print(f"held-out accuracy healthy/faulty by mean |command| (evidence needs {need:.2f}):")
    for lower, windows, accuracy in floor["bands"]:
        print(
            f"  {lower:.2f}-{lower + floor['band_width']:.2f} {windows:7d} windows  {accuracy:.3f}"
        )
    if floor["min_command_abs"] is None:
        print(
            f"warning: no band reaches {need:.2f}: every window will be answered unknown "
            "(low_excitation); train on more units and operating points or lower "
            "--min-band-accuracy",
            file=sys.stderr,
        )
    else:
        print(f"windows give evidence from mean |command| {floor['min_command_abs']:.2f}")
    return EXIT_OK
