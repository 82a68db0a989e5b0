"""``thruster-fdd diagnose``: offline diagnosis of a trace through the nodes' code path, with the
label changes the node would publish, the first fault, and ``--expect`` as a check for CI."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES, UNKNOWN
from thruster_fdd_shore.commands.common import (
    EXIT_FAILED,
    EXIT_OK,
    check_output,
    positive_float,
)

if TYPE_CHECKING:
    from thruster_fdd.core.traces.data import Trace

NAME = "diagnose"
HELP = "offline diagnosis of a trace: label changes, first fault, overall (JSON); --expect for CI"
DESCRIPTION = (
    "Diagnose a trace (CSV, MCAP, or a rosbag2 bag folder) with the exported models (DIR/nominal "
    "and DIR/classifier) through the same residual, window and decision code as the nodes: one "
    "decision per --hop seconds. Prints each change of the published label with its time, the "
    "first fault and an overall answer in which a fault anywhere wins. JSON (--json): start, "
    "overall {label, confidence}, events [{t, label, confidence}], first_fault {label, t, "
    "onset_t} or null, windows [...]; times on the trace's clock, s. --expect LABEL[@T] makes "
    "the exit code a check: 0 when LABEL is published (its first publication at least T s "
    "after the trace starts, when given), 1 when not, 2 on bad input."
)


def expectation(text: str) -> tuple[str, float | None]:
    """argparse type of ``--expect``: ``LABEL`` or ``LABEL@SECONDS``."""
    label, at, seconds = text.partition("@")
    if label not in (*CLASS_NAMES, UNKNOWN):
        raise argparse.ArgumentTypeError(
            f"unknown label {label!r}; expected one of {', '.join((*CLASS_NAMES, UNKNOWN))}"
        )
    if not at:
        return label, None
    try:
        t = float(seconds)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a time in s after '@': {seconds!r}") from None
    if not 0.0 <= t < float("inf"):
        raise argparse.ArgumentTypeError(f"the time after '@' must be >= 0 s, got {seconds}")
    return label, t


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd diagnose``."""
    p.add_argument("trace", type=Path, metavar="TRACE", help="CSV, MCAP or bag folder")
    p.add_argument(
        "--models",
        type=Path,
        metavar="DIR",
        help="folder with nominal/ and classifier/ (default: $THRUSTER_FDD_MODELS, else the "
        "workspace's models/)",
    )
    p.add_argument("--json", type=Path, metavar="OUT", help="write the result as JSON here")
    p.add_argument("--hop", type=positive_float, default=1.0, help="time between decisions, s")
    p.add_argument("--thruster", metavar="ID", help="thruster of a recording (default: first)")
    p.add_argument(
        "--expect",
        type=expectation,
        metavar="LABEL[@T]",
        help="exit 0 only if LABEL is published (first at least T s after the start), else 1",
    )


def check_expectation(result: dict, label: str, after_s: float | None) -> tuple[bool, str]:
    """Whether ``result`` (the ``diagnose`` JSON) publishes ``label`` (first at least
    ``after_s`` s after its start), and a line saying so."""
    start = result["start"]
    times = [e["t"] - start for e in result["events"] if e["label"] == label]
    if not times:
        return False, f"expected {label}: never published"
    if after_s is not None and times[0] < after_s:
        return False, f"expected {label} from {after_s:g} s: first published at {times[0]:.1f} s"
    return True, f"expected {label}: published at {times[0]:.1f} s"


def _replayed_samples(
    trace: Trace, recording: Path, models: Path, hop_s: float
) -> tuple[Trace, dict[str, int]]:
    """The samples of a recording's ``trace`` that ``replay`` publishes (the live model's, from
    where fresh nodes reproduce the live decisions: ``replay_check.align_bag``), and the live
    decisions not reproduced, by reason."""
    import warnings

    from thruster_fdd.core.errors import PartialInputWarning
    from thruster_fdd_shore.core.traces.replay_check import (
        chain_timing,
        load_recording,
        replayed_samples,
    )

    # Reading the trace warned about damage and skipped splits already.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PartialInputWarning)
        bags = load_recording(recording, chain_timing(models, hop_s))
    for bag in bags:
        if bag.thruster_id == trace.thruster_id:
            reasons = bag.comparable.not_comparable if bag.comparable is not None else {}
            return replayed_samples(trace, bag), dict(reasons)
    return trace, {}


def run(args: argparse.Namespace) -> int:
    """Diagnose ``args.trace``; print the label changes; check ``--expect``."""
    from thruster_fdd.core.artifact import CARD_FILE, default_models_dir
    from thruster_fdd_shore.core.traces.files import is_bag, read_traces

    # The input first: a typo answers at once, before torch (about 2.4 s) is imported.
    if not args.trace.exists():
        raise BadInputError(f"{args.trace}: no such trace file or bag folder")
    models = args.models if args.models is not None else default_models_dir()
    for stage in ("nominal", "classifier"):
        if not (models / stage / CARD_FILE).is_file():
            raise BadInputError(f"{models / stage}: no exported model ({CARD_FILE}) (--models)")
    if args.json is not None:
        check_output(args.json, "--json")
    traces = read_traces([args.trace])
    if args.thruster is not None:
        traces = [t for t in traces if t.thruster_id == args.thruster]
        if not traces:
            raise BadInputError(f"{args.trace}: no thruster {args.thruster!r}")
    elif len(traces) > 1:
        ids = ", ".join(str(t.thruster_id) for t in traces)
        print(f"note: {args.trace} holds {len(traces)} traces ({ids}); using the first "
              "(--thruster ID)", file=sys.stderr)  # fmt: skip
    trace = traces[0]
    not_comparable: dict[str, int] = {}
    if is_bag(args.trace) or args.trace.suffix == ".mcap":
        trace, not_comparable = _replayed_samples(trace, args.trace, models, args.hop)
    import torch

    from thruster_fdd_shore.core.diagnosis.offline import diagnose_trace

    torch.set_num_threads(1)
    result = diagnose_trace(trace, models / "nominal", models / "classifier", hop_s=args.hop)
    if not_comparable:
        result["not_comparable"] = not_comparable
    if not result["windows"]:
        span = float(trace.t[-1] - trace.t[0]) if len(trace) else 0.0
        raise BadInputError(
            f"{args.trace}: {len(trace)} sample(s) over {span:.1f} s hold no full decision "
            "window; nothing to diagnose"
        )
    if args.json is not None:
        write_text(args.json, json.dumps(result, indent=1) + "\n")
    if not_comparable:
        from thruster_fdd_shore.core.traces.replay_check import NOT_COMPARABLE_REASONS

        for reason, n in not_comparable.items():
            print(f"note: {n} live decision(s) not reproduced: {NOT_COMPARABLE_REASONS[reason]}",
                  file=sys.stderr)  # fmt: skip
    start, overall, fault = result["start"], result["overall"], result["first_fault"]
    print(
        f"{args.trace}: {overall['label']} (confidence {overall['confidence']:.2f}) over "
        f"{len(result['windows'])} window(s); times from the trace's start ({start:.3f} s)"
    )
    for e in result["events"]:
        print(f"  from {e['t'] - start:8.1f} s: {e['label']} ({e['confidence']:.2f})")
    if fault is None:
        print("  no fault published")
    else:
        print(
            f"  first fault: {fault['label']} published at {fault['t'] - start:.1f} s "
            f"(began about {fault['onset_t'] - start:.1f} s)"
        )
    if result["quiet_allowance"] is not None:
        print(
            f"  quiet allowance: {result['quiet_allowance']:.2f} nats (a unit_allowance above it "
            "publishes no fault on this trace)"
        )
    if args.expect is None:
        return EXIT_OK
    ok, line = check_expectation(result, *args.expect)
    print(line, file=sys.stdout if ok else sys.stderr)
    return EXIT_OK if ok else EXIT_FAILED
