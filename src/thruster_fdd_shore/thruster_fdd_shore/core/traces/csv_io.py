"""Trace CSV files (docs/contracts.md, "Trace CSV") and command-history CSV files."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from thruster_fdd.core.atomic import replaced_file
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.traces.data import (
    TRACE_COLUMNS,
    Trace,
    check_time,
    check_units,
    finite_rows,
)


def write_trace_csv(trace: Trace, path: str | Path) -> None:
    """Write ``trace`` as a trace CSV (the columns, then ``condition`` / ``thruster_id``).

    The file appears whole or not at all (``core.atomic``).

    Parameters
    ----------
    trace : Trace
        The trace to write.
    path : str or Path
        Destination file; parent folders are created.
    """
    header = list(TRACE_COLUMNS) + list(trace.extra)
    labels = trace.sample_labels()
    if labels is not None:
        header.append("condition")
    if trace.thruster_id is not None:
        header.append("thruster_id")
    columns = [getattr(trace, c) for c in TRACE_COLUMNS] + list(trace.extra.values())
    with replaced_file(path) as tmp, tmp.open("w", newline="") as f:
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


def _read_rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    """The header and rows of a CSV file; BadInputError when it is not a readable CSV."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f)
            fields = [name.strip() for name in reader.fieldnames or []]
            twice = sorted({name for name in fields if name and fields.count(name) > 1})
            if twice:
                raise BadInputError(f"{path}: column(s) {', '.join(twice)} appear more than once")
            rows = [{k.strip(): (v or "").strip() for k, v in row.items() if k} for row in reader]
    except UnicodeDecodeError as exc:
        raise BadInputError(f"{path}: not a text CSV file (byte {exc.start} is not UTF-8)") from exc
    except csv.Error as exc:
        raise BadInputError(f"{path}: not a readable CSV file ({exc})") from exc
    return fields, rows


def read_trace_csv(path: str | Path) -> Trace:
    """Read a trace CSV with at least the columns of ``TRACE_COLUMNS``.

    Extra numeric columns are kept in ``Trace.extra``. A ``condition`` column with one class
    name gives ``Trace.condition``; one whose name changes (a fault mid-run) gives ``labels``.
    Rows with a non-finite number (``nan``, ``inf``) are left out with a ``TraceWarning``.

    Raises
    ------
    BadInputError
        If the file is not a text CSV, a column is missing or appears twice, a value is not a
        number, times do not increase, a column is plausibly in the wrong unit (a pulse width
        in the command column, milliseconds in the time column: ``data.check_units``), a label
        is missing on some rows, or ``thruster_id`` changes within the file.
    """
    path = Path(path)
    fields, rows = _read_rows(path)
    if not fields:
        expected = ", ".join(TRACE_COLUMNS)
        raise BadInputError(f"{path}: empty file, expected a header with {expected}")
    missing = [c for c in TRACE_COLUMNS if c not in fields]
    if missing:
        found = ", ".join(f or "''" for f in fields)
        raise BadInputError(
            f"{path}: missing trace column(s) {', '.join(missing)}; expected the columns "
            f"{', '.join(TRACE_COLUMNS)} (units in docs/contracts.md, 'Trace CSV'), found {found}"
        )
    if not rows:
        raise BadInputError(f"{path}: no samples")
    numeric = [c for c in fields if c and c not in ("condition", "thruster_id")]
    values: dict[str, np.ndarray] = {}
    for name in numeric:
        try:
            values[name] = np.array([float(r[name]) for r in rows])
        except ValueError as exc:
            raise BadInputError(
                f"{path}: column {name!r} holds a value that is not a number"
            ) from exc
    values["_row"] = np.arange(len(rows), dtype=float)
    values = finite_rows(values, str(path))
    kept = values.pop("_row").astype(int)
    rows = [rows[i] for i in kept]
    check_time(values["t"], str(path))
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
    try:
        trace = Trace(
            **{c: values[c] for c in TRACE_COLUMNS},
            condition=condition,
            thruster_id=thruster_id,
            extra=extra,
            labels=labels_or_none,
        )
    except BadInputError as exc:
        raise BadInputError(f"{path}: {exc}") from None
    check_units(trace, str(path))
    return trace


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
    BadInputError
        If the file is not a text CSV, a column is missing or appears twice, a value is not a
        finite number, times do not increase or a command lies outside -1..1 (a pulse width in
        µs is named).
    """
    path = Path(path)
    fields, rows = _read_rows(path)
    if "t" not in fields or "command" not in fields:
        raise BadInputError(f"{path}: needs columns t and command, has {fields}")
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
        hint = ""
        if 800.0 <= float(np.median(command)) <= 2200.0:
            hint = "; it looks like a pulse width in µs: command = (pwm_us - 1500) / 400"
        raise BadInputError(f"{path}: command must lie within -1..1{hint}")
    return t, command
