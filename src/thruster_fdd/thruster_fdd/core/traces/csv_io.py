"""Trace CSV files (docs/contracts.md, "Trace CSV") and command-history CSV files."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.traces.data import TRACE_COLUMNS, Trace


def write_trace_csv(trace: Trace, path: str | Path) -> None:
    """Write ``trace`` as a trace CSV (the columns, then ``condition`` / ``thruster_id``).

    Parameters
    ----------
    trace : Trace
        The trace to write.
    path : str or Path
        Destination file; parent folders are created.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = list(TRACE_COLUMNS) + list(trace.extra)
    labels = trace.sample_labels()
    if labels is not None:
        header.append("condition")
    if trace.thruster_id is not None:
        header.append("thruster_id")
    columns = [getattr(trace, c) for c in TRACE_COLUMNS] + list(trace.extra.values())
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for i in range(len(trace)):
            row: list[str] = [f"{float(col[i]):.6g}" for col in columns]
            row[0] = f"{float(trace.t[i]):.6f}"
            if labels is not None:
                row.append(str(labels[i]))
            if trace.thruster_id is not None:
                row.append(trace.thruster_id)
            writer.writerow(row)


def read_trace_csv(path: str | Path) -> Trace:
    """Read a trace CSV with at least the columns of ``TRACE_COLUMNS``.

    Extra numeric columns are kept in ``Trace.extra``. A ``condition`` column with one class
    name gives ``Trace.condition``; one whose name changes (a fault mid-run) gives ``labels``.

    Raises
    ------
    ValueError
        If a required column is missing, a value is not a number, a label is missing on some
        rows, or ``thruster_id`` changes within the file.
    """
    path = Path(path)
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        if reader.fieldnames is None:
            expected = ", ".join(TRACE_COLUMNS)
            raise BadInputError(f"{path}: empty file, expected a header with {expected}")
        fields = [name.strip() for name in reader.fieldnames]
        missing = [c for c in TRACE_COLUMNS if c not in fields]
        if missing:
            raise BadInputError(f"{path}: missing trace column(s) {', '.join(missing)}")
        rows = [{k.strip(): (v or "").strip() for k, v in row.items() if k} for row in reader]
    if not rows:
        raise BadInputError(f"{path}: no samples")
    numeric = [c for c in fields if c not in ("condition", "thruster_id")]
    values: dict[str, np.ndarray] = {}
    for name in numeric:
        try:
            values[name] = np.array([float(r[name]) for r in rows])
        except ValueError as exc:
            raise BadInputError(
                f"{path}: column {name!r} holds a value that is not a number"
            ) from exc
    labels = np.array([r.get("condition", "") for r in rows], dtype=object)
    if "condition" not in fields or not labels.any():
        labels_or_none, condition = None, None
    elif (labels == "").any():
        raise BadInputError(f"{path}: column 'condition' is empty on some rows")
    elif (labels == labels[0]).all():
        labels_or_none, condition = None, str(labels[0])
    else:
        labels_or_none, condition = labels, None
    thruster_id = _single_label(path, rows, "thruster_id")
    extra = {k: v for k, v in values.items() if k not in TRACE_COLUMNS}
    return Trace(
        **{c: values[c] for c in TRACE_COLUMNS},
        condition=condition,
        thruster_id=thruster_id,
        extra=extra,
        labels=labels_or_none,
    )


def _single_label(path: Path, rows: list[dict[str, str]], column: str) -> str | None:
    labels = {r.get(column, "") for r in rows} - {""}
    if len(labels) > 1:
        raise BadInputError(f"{path}: column {column!r} mixes {sorted(labels)}; one value per file")
    return labels.pop() if labels else None


def read_command_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a command history: CSV columns ``t`` (s, increasing) and ``command`` (-1..1).

    Returns
    -------
    (t, command) : tuple of np.ndarray, each shape (n,)

    Raises
    ------
    ValueError
        If a column is missing, a value is not a finite number, times do not increase or a
        command lies outside -1..1.
    """
    path = Path(path)
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        fields = [name.strip() for name in reader.fieldnames or []]
        if "t" not in fields or "command" not in fields:
            raise BadInputError(f"{path}: needs columns t and command, has {fields}")
        rows = [{k.strip(): v for k, v in row.items() if k} for row in reader]
    try:
        t = np.array([float(r["t"]) for r in rows])
        command = np.array([float(r["command"]) for r in rows])
    except ValueError as exc:
        raise BadInputError(f"{path}: t and command must be numbers") from exc
    if len(t) < 2:
        raise BadInputError(f"{path}: needs at least two rows")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(command))):
        raise BadInputError(f"{path}: t and command must be finite")
    if not np.all(np.diff(t) > 0):
        raise BadInputError(f"{path}: t must be strictly increasing")
    if np.any(np.abs(command) > 1.0):
        raise BadInputError(f"{path}: command must lie within -1..1")
    return t, command
