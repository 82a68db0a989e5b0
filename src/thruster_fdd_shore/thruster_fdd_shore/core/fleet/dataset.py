"""The fleet dataset: Parquet files partitioned by vehicle and thruster (hive style,
``DATASET/vehicle=<id>/thruster=<id>/*.parquet``), one row per recording and thruster, plus
``DATASET/_scan.json`` with what the scan was run on (archive, models, decision settings).

Columns (``SCHEMA``; times are UTC timestamps, ms): identity (``vehicle``, ``thruster``,
``recording`` relative to the archive, ``digest`` SHA-256 of its files, ``size_bytes``,
``mtime_ns``), time span (``start``, ``end``, ``duration_s``), ``samples`` (telemetry) and
``decisions``, ``frac_<label>`` (share of time each label was published, the six classes and
``unknown``), ``first_fault_label`` and ``first_fault`` (time it was first published),
``fault_prob_mean`` / ``fault_prob_max`` (summed probability of the fault classes over the
decisions), ``confidence_mean``, ``eff_q10`` / ``eff_q50`` / ``eff_q90`` (quantiles of the
published effectiveness, estimates with at least ``scan.MIN_EVIDENCE_S`` s of evidence),
``eff_last`` / ``eff_std_last`` / ``eff_family`` / ``eff_severity`` / ``eff_evidence_s`` (the fit
at the end), ``rms_rpm_<band>`` / ``rms_current_a_<band>`` (residual RMS per speed band of
``scan.SPEED_BANDS_RPM``), ``events`` (label changes, ``offset_s:label;...`` from ``start``),
model ids and ``models_digest``, ``problems`` (what of a damaged recording was lost), ``error``
(empty unless the recording could not be read: then ``thruster`` is ``scan.ERROR_THRUSTER``) and
``scanned_at``.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.parquet as pq

from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.core.fleet.scan import LABELS, SPEED_BANDS_RPM

_TS = pa.timestamp("ms", tz="UTC")

SCHEMA = pa.schema(
    [
        ("vehicle", pa.string()),
        ("thruster", pa.string()),
        ("recording", pa.string()),
        ("digest", pa.string()),
        ("size_bytes", pa.int64()),
        ("mtime_ns", pa.int64()),
        ("start", _TS),
        ("end", _TS),
        ("duration_s", pa.float64()),
        ("samples", pa.int64()),
        ("decisions", pa.int64()),
        *((f"frac_{label}", pa.float64()) for label in LABELS),
        ("first_fault_label", pa.string()),
        ("first_fault", _TS),
        ("fault_prob_mean", pa.float64()),
        ("fault_prob_max", pa.float64()),
        ("confidence_mean", pa.float64()),
        ("eff_q10", pa.float64()),
        ("eff_q50", pa.float64()),
        ("eff_q90", pa.float64()),
        ("eff_last", pa.float64()),
        ("eff_std_last", pa.float64()),
        ("eff_family", pa.string()),
        ("eff_severity", pa.float64()),
        ("eff_evidence_s", pa.float64()),
        *((f"rms_rpm_{band}", pa.float64()) for band, _, _ in SPEED_BANDS_RPM),
        *((f"rms_current_a_{band}", pa.float64()) for band, _, _ in SPEED_BANDS_RPM),
        ("events", pa.string()),
        ("nominal_model_id", pa.string()),
        ("classifier_model_id", pa.string()),
        ("reference_id", pa.string()),
        ("models_digest", pa.string()),
        ("problems", pa.string()),
        ("error", pa.string()),
        ("scanned_at", _TS),
    ]
)
"""Columns of the dataset, in order."""

PARTITIONING = pads.partitioning(
    pa.schema([("vehicle", pa.string()), ("thruster", pa.string())]), flavor="hive"
)

SCAN_FILE = "_scan.json"
"""What the scan was run on (pyarrow skips files starting with ``_``)."""

_SECONDS = {"start": "start_s", "end": "end_s", "first_fault": "first_fault_s"}


def to_table(rows: Iterable[dict[str, Any]]) -> pa.Table:
    """Rows of ``scan.scan_recording`` (times in s since the epoch) as a table of ``SCHEMA``."""
    rows = list(rows)
    data: dict[str, list[Any]] = {}
    for field in SCHEMA:
        if field.name == "scanned_at":
            values = [r.get("scanned_at_s") for r in rows]
        else:
            values = [r.get(_SECONDS.get(field.name, field.name)) for r in rows]
        if pa.types.is_timestamp(field.type):
            values = [None if v is None else round(v * 1000.0) for v in values]
            data[field.name] = pa.array(values, pa.int64()).cast(field.type)
        else:
            data[field.name] = pa.array(values, field.type)
    return pa.table(data, schema=SCHEMA)


def write_rows(root: Path, rows: list[dict[str, Any]], tag: str) -> None:
    """Append rows to the dataset at ``root`` as new Parquet files (one per partition)."""
    if not rows:
        return
    pq.write_to_dataset(
        to_table(rows),
        root_path=str(root),
        partitioning=PARTITIONING,
        basename_template=f"part-{tag}-{uuid.uuid4().hex[:8]}-{{i}}.parquet",
        existing_data_behavior="overwrite_or_ignore",
    )


def read_dataset(root: str | Path, columns: list[str] | None = None) -> pa.Table:
    """The whole dataset (or some columns), sorted by vehicle, thruster and start.

    Raises
    ------
    BadInputError
        If ``root`` is not a fleet dataset folder.
    """
    root = Path(root)
    if not root.is_dir():
        raise BadInputError(f"{root}: no such dataset folder")
    if not any(root.rglob("*.parquet")):
        if (root / SCAN_FILE).is_file():
            return SCHEMA.empty_table().select(columns or SCHEMA.names)
        raise BadInputError(f"{root}: not a fleet dataset (no .parquet file)")
    try:
        dataset = pads.dataset(root, format="parquet", partitioning=PARTITIONING, schema=SCHEMA)
        table = dataset.to_table(columns=columns)
    except (pa.ArrowInvalid, OSError) as exc:
        raise BadInputError(f"{root}: unreadable fleet dataset ({exc})") from None
    keys = [k for k in ("vehicle", "thruster", "start") if k in table.column_names]
    return table.sort_by([(k, "ascending") for k in keys]) if keys else table


def write_scan_info(root: Path, info: dict[str, Any]) -> None:
    """Write ``_scan.json`` (archive, models, settings of the latest scan)."""
    root.mkdir(parents=True, exist_ok=True)
    write_text(root / SCAN_FILE, json.dumps(info, indent=1) + "\n")


def read_scan_info(root: Path) -> dict[str, Any]:
    """``_scan.json`` of a dataset.

    Raises
    ------
    BadInputError
        If it is missing or not JSON.
    """
    path = Path(root) / SCAN_FILE
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise BadInputError(f"{root}: not a fleet dataset (no {SCAN_FILE})") from None
    except ValueError as exc:
        raise BadInputError(f"{path}: not JSON ({exc})") from None


def as_rows(table: pa.Table) -> list[dict[str, Any]]:
    """A dataset table as rows with the times in s since the epoch (``start_s``, ``end_s``,
    ``first_fault_s``, ``scanned_at_s``), as ``scan.scan_recording`` returns them."""
    names = {**_SECONDS, "scanned_at": "scanned_at_s"}
    out = []
    for row in table.to_pylist():
        for col, key in names.items():
            if col in row:
                value = row.pop(col)
                row[key] = None if value is None else value.timestamp()
        out.append(row)
    return out
