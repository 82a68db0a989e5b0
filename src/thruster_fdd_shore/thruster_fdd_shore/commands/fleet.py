"""``thruster-fdd fleet scan|report|compare|dataset``: fleet health over a recording archive, on
Dask (docs/fleet.md)."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from dataclasses import asdict
from pathlib import Path

from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.commands.common import (
    EXIT_FAILED,
    EXIT_OK,
    check_output,
    non_negative_int,
    positive_float,
)

NAME = "fleet"
HELP = "fleet health over a recording archive on Dask: scan, report, compare, dataset"
DESCRIPTION = (
    "Scan every recording (rosbag2 bag folder or MCAP file; vehicle = the first folder under the "
    "archive) with the vehicle's own residual, decision and effectiveness code into a Parquet "
    "dataset partitioned by vehicle and thruster, on a Dask cluster (a local one by default); "
    "report trends and faults over calendar time; compare a new model pair with the one that "
    "scanned; export healthy stretches for 'train nominal'. docs/fleet.md."
)


def _probability(text: str) -> float:
    value = positive_float(text)
    if value >= 1.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1), got {text}")
    return value


def _share(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be in [0, 1], got {text}")
    return value


def _cluster_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run on this existing Dask scheduler (its workers must see the archive and the "
        "models at the same paths) instead of a local cluster",
    )
    p.add_argument(
        "--workers",
        type=non_negative_int,
        default=0,
        metavar="N",
        help="worker processes of the local cluster (0: one per core)",
    )
    p.add_argument(
        "--retries", type=non_negative_int, default=2, help="extra attempts of a failing task"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd fleet`` and its four actions."""
    what = p.add_subparsers(dest="what", metavar="{scan,report,compare,dataset}", required=True)
    fmt = argparse.ArgumentDefaultsHelpFormatter
    s = what.add_parser(
        "scan",
        help="scan an archive into the Parquet dataset (skips what it holds)",
        description=(
            "One Dask task per recording, its thrusters streamed sample by sample through "
            "ResidualStream, DiagnosisStream and EffectivenessEstimator; one row per recording "
            "and thruster appended to DATASET (a recording already there by digest is "
            "skipped; an unreadable one becomes an error row). Exit 1 when a task still "
            "fails after its retries (not written: the next scan tries again)."
        ),
        formatter_class=fmt,
    )
    s.add_argument("archive", type=Path, metavar="ARCHIVE", help="folder of recordings")
    s.add_argument("--out", type=Path, required=True, metavar="DATASET", help="dataset folder")
    s.add_argument(
        "--models", type=Path, default=Path("models"), metavar="DIR",
        help="folder with nominal/, classifier/ and reference/",
    )  # fmt: skip
    s.add_argument("--hop", type=positive_float, default=1.0, help="time between decisions, s")
    s.add_argument(
        "--hysteresis", type=int, default=2, help="agreeing windows before a label change"
    )
    _cluster_options(s)
    r = what.add_parser(
        "report",
        help="static HTML page and Markdown summary of a dataset",
        description=(
            "Writes DIR/index.html (plots embedded), DIR/summary.md and DIR/summary.json: "
            "effectiveness and fault probability of every thruster over calendar time, trends "
            "(one-sided Mann-Kendall test for a decrease of the median effectiveness, "
            "Theil-Sen slope, Bonferroni over the thrusters: family-wise false-alarm rate "
            "--alpha), faults with their first recording, recordings that failed."
        ),
        formatter_class=fmt,
    )
    r.add_argument("dataset", type=Path, metavar="DATASET", help="dataset folder of 'fleet scan'")
    r.add_argument("--out", type=Path, required=True, metavar="DIR", help="report folder")
    r.add_argument("--alpha", type=_probability, default=0.05, help="family-wise false-alarm rate")
    c = what.add_parser(
        "compare",
        help="where a new model pair publishes something else than the scanning pair",
        description=(
            "Re-runs every readable recording of DATASET (from the archive its _scan.json "
            "names) with the model pair NEW and lists each recording and thruster whose "
            "published labels differ for more than --tolerance of its time or whose first "
            "fault differs. Exit 0 when none differ, 1 when some do."
        ),
        formatter_class=fmt,
    )
    c.add_argument("dataset", type=Path, metavar="DATASET", help="dataset folder of 'fleet scan'")
    c.add_argument(
        "--models", type=Path, required=True, metavar="NEW",
        help="folder with the new nominal/, classifier/ and reference/",
    )  # fmt: skip
    c.add_argument("--tolerance", type=_share, default=0.0, help="share of time labels may differ")
    c.add_argument("--json", type=Path, metavar="OUT", help="also write the differences as JSON")
    _cluster_options(c)
    d = what.add_parser(
        "dataset",
        help="export training traces from a dataset (--healthy)",
        description=(
            "With --healthy: every span of a recording over which a nominal class was "
            "published for at least --min-s, in recordings without a fault and with 10 %% "
            "effectiveness quantile >= --min-effectiveness, cut from the archive and written "
            "as trace CSVs OUT/<vehicle>/<thruster>/*.csv (condition = the published class), "
            "ready for 'thruster-fdd train nominal --data OUT/<vehicle>/<thruster>'."
        ),
        formatter_class=fmt,
    )
    d.add_argument("dataset", type=Path, metavar="DATASET", help="dataset folder of 'fleet scan'")
    d.add_argument(
        "--healthy", action="store_true", required=True, help="export the healthy stretches"
    )
    d.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder of trace CSVs")
    d.add_argument("--min-s", type=positive_float, default=30.0, help="shortest stretch, s")
    d.add_argument(
        "--min-effectiveness", type=_share, default=0.9, help="least 10 %% effectiveness quantile"
    )


def _scan(args: argparse.Namespace) -> int:
    from thruster_fdd_shore.core.fleet.runner import dask_client, plan_scan, scan_archive
    from thruster_fdd_shore.core.fleet.scan import ScanConfig, load_pair

    if not args.archive.is_dir():
        raise BadInputError(f"{args.archive}: no such archive folder")
    check_output(args.out, "--out", folder=True)
    config = ScanConfig(str(args.models.absolute()), args.hop, args.hysteresis)
    load_pair(config.models)
    plan = plan_scan(args.archive, args.out)
    with contextlib.ExitStack() as stack:
        client = (
            stack.enter_context(dask_client(args.scheduler, args.workers or None))
            if plan[1]
            else None
        )
        result = scan_archive(
            args.archive, args.out, config, client,
            retries=args.retries, progress=not args.no_progress, plan=plan,
        )  # fmt: skip
    rate = result.samples / result.seconds if result.seconds > 0 else 0.0
    print(
        f"{args.out}: {result.found} recording(s) found, {result.skipped} already scanned, "
        f"{result.scanned} scanned ({result.rows} rows, {result.samples} samples, "
        f"{rate:.0f} samples/s), {len(result.errors)} unreadable, {len(result.failed)} failed"
    )
    for rec in result.errors:
        print(f"  unreadable (error row): {rec}")
    for rec, why in result.failed:
        print(f"  failed after retries (not written): {rec}: {why}", file=sys.stderr)
    return EXIT_FAILED if result.failed else EXIT_OK


def _report(args: argparse.Namespace) -> int:
    from thruster_fdd_shore.core.fleet.report import write_report

    check_output(args.out, "--out", folder=True)
    summary = write_report(args.dataset, args.out, args.alpha)
    flagged = [k for k, t in summary["trends"].items() if t["flagged"]]
    print(
        f"{args.out / 'index.html'}: {summary['recordings']} recording(s), "
        f"{summary['tested']} thruster(s) tested, trend on {len(flagged)}"
        + (f" ({', '.join(flagged)})" if flagged else "")
        + f", {len(summary['faults'])} with a fault, {len(summary['failed'])} failed recording(s)"
    )
    return EXIT_OK


def _compare(args: argparse.Namespace) -> int:
    from thruster_fdd_shore.core.fleet.archive import find_recordings, recording_digest
    from thruster_fdd_shore.core.fleet.compare import differences
    from thruster_fdd_shore.core.fleet.dataset import as_rows, read_dataset, read_scan_info
    from thruster_fdd_shore.core.fleet.runner import dask_client, run_tasks
    from thruster_fdd_shore.core.fleet.scan import ScanConfig, load_pair

    info = read_scan_info(args.dataset)
    old = [r for r in as_rows(read_dataset(args.dataset)) if not r["error"]]
    config = ScanConfig(str(args.models.absolute()), info["hop_s"], info["hysteresis"])
    load_pair(config.models)
    wanted = {r["recording"]: r["digest"] for r in old}
    tasks = []
    for rec in find_recordings(info["archive"]):
        if rec.relative in wanted:
            digest = recording_digest(rec.path)
            if digest != wanted[rec.relative]:
                print(f"note: {rec.relative} changed since the scan; left out", file=sys.stderr)
                continue
            tasks.append((rec, digest))
    with dask_client(args.scheduler, args.workers or None) as client:
        new, failed = run_tasks(
            client, tasks, config, retries=args.retries, progress=not args.no_progress
        )
    for rec, why in failed:
        print(f"  failed after retries: {rec}: {why}", file=sys.stderr)
    found, compared = differences(old, new, args.tolerance)
    if args.json is not None:
        payload = {"compared": compared, "differences": [asdict(d) for d in found]}
        write_text(args.json, json.dumps(payload, indent=1) + "\n")
    print(
        f"{args.dataset}: {compared} recording-thruster(s) compared with {args.models}; "
        f"{len(found)} differ"
    )
    for d in found:
        print(
            f"  {d.vehicle}/{d.thruster} {d.recording}: labels differ {d.share:.1%} of the time; "
            f"first fault {d.old_fault or 'none'} -> {d.new_fault or 'none'}"
        )
    return EXIT_FAILED if found or failed else EXIT_OK


def _dataset(args: argparse.Namespace) -> int:
    from thruster_fdd_shore.core.fleet.dataset import as_rows, read_dataset, read_scan_info
    from thruster_fdd_shore.core.fleet.healthy import stretches, write_stretches

    check_output(args.out, "--out", folder=True)
    info = read_scan_info(args.dataset)
    rows = as_rows(read_dataset(args.dataset))
    found = stretches(rows, min_s=args.min_s, min_effectiveness=args.min_effectiveness)
    files = write_stretches(Path(info["archive"]), found, args.out)
    units = sorted({f.parent.relative_to(args.out).as_posix() for f in files})
    print(f"{args.out}: {len(files)} healthy stretch(es) of {len(units)} unit(s)")
    for unit in units:
        n = sum(1 for f in files if f.parent.relative_to(args.out).as_posix() == unit)
        print(f"  {unit}: {n} trace(s)")
    return EXIT_OK


def run(args: argparse.Namespace) -> int:
    """Run ``thruster-fdd fleet <what>``."""
    return {"scan": _scan, "report": _report, "compare": _compare, "dataset": _dataset}[args.what](
        args
    )
