"""Trace data: the interchange format of DESIGN.md (trace CSV), as a typed, ROS-free container."""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

CLASS_NAMES: tuple[str, ...] = (
    "nominal_15v",
    "nominal_13v",
    "nominal_11v8",
    "broken_blade_1",
    "broken_blade_2",
    "biofouling",
)
"""The six conditions, spelled as in DESIGN.md (CSV ``condition`` column, model cards, labels)."""

TRACE_COLUMNS: tuple[str, ...] = ("t", "command", "voltage", "rpm", "current")
"""Required trace CSV columns, in order: s, normalised command (-1..1), V, rpm, A."""


@dataclass(frozen=True)
class Trace:
    """One recorded or simulated telemetry trace of one thruster.

    Attributes
    ----------
    t : np.ndarray, shape (n,)
        Sample times in s, strictly increasing.
    command : np.ndarray, shape (n,)
        Applied command, normalised to -1..1 (``(pwm_us - 1500) / 400``).
    voltage : np.ndarray, shape (n,)
        Bus voltage in V.
    rpm : np.ndarray, shape (n,)
        Shaft speed in rpm, signed (negative in reverse).
    current : np.ndarray, shape (n,)
        Bus current in A.
    condition : str or None
        Class name (one of ``CLASS_NAMES``) when the whole trace has one label, else None.
    thruster_id : str or None
        Which thruster produced the trace, when known.
    extra : dict of str to np.ndarray
        Further numeric columns, each shape (n,) (e.g. ``temperature``).
    labels : np.ndarray or None, shape (n,)
        Per-sample class names when the label changes within the trace (a fault that starts
        mid-run); then ``condition`` is None.
    """

    t: np.ndarray
    command: np.ndarray
    voltage: np.ndarray
    rpm: np.ndarray
    current: np.ndarray
    condition: str | None = None
    thruster_id: str | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    labels: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.t)
        for name in TRACE_COLUMNS:
            arr = getattr(self, name)
            if not isinstance(arr, np.ndarray) or arr.ndim != 1:
                raise ValueError(f"trace column {name!r} must be a 1-D numpy array")
            if len(arr) != n:
                raise ValueError(f"trace column {name!r} has {len(arr)} samples, 't' has {n}")
        for name, arr in self.extra.items():
            if len(arr) != n:
                raise ValueError(f"extra column {name!r} has {len(arr)} samples, 't' has {n}")
        if n > 1 and not np.all(np.diff(self.t) > 0):
            raise ValueError("trace column 't' must be strictly increasing")
        names = set() if self.condition is None else {self.condition}
        if self.labels is not None:
            if self.condition is not None:
                raise ValueError("give either one condition or per-sample labels, not both")
            if len(self.labels) != n:
                raise ValueError(f"labels have {len(self.labels)} entries, 't' has {n}")
            names = set(self.labels.tolist())
        unknown = names - set(CLASS_NAMES)
        if unknown:
            raise ValueError(
                f"unknown condition {sorted(unknown)}; expected one of {', '.join(CLASS_NAMES)}"
            )

    def __len__(self) -> int:
        return len(self.t)

    def sample_labels(self) -> np.ndarray | None:
        """Class name of every sample, shape (n,); None when the trace is unlabelled."""
        if self.labels is not None:
            return self.labels
        if self.condition is not None:
            return np.full(len(self), self.condition, dtype=object)
        return None


def write_trace_csv(trace: Trace, path: str | Path) -> None:
    """Write ``trace`` as a trace CSV (DESIGN.md columns, then ``condition``/``thruster_id``).

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
            raise ValueError(f"{path}: empty file, expected a header with {expected}")
        fields = [name.strip() for name in reader.fieldnames]
        missing = [c for c in TRACE_COLUMNS if c not in fields]
        if missing:
            raise ValueError(f"{path}: missing trace column(s) {', '.join(missing)}")
        rows = [{k.strip(): (v or "").strip() for k, v in row.items() if k} for row in reader]
    if not rows:
        raise ValueError(f"{path}: no samples")
    numeric = [c for c in fields if c not in ("condition", "thruster_id")]
    values: dict[str, np.ndarray] = {}
    for name in numeric:
        try:
            values[name] = np.array([float(r[name]) for r in rows])
        except ValueError as exc:
            raise ValueError(f"{path}: column {name!r} holds a value that is not a number") from exc
    labels = np.array([r.get("condition", "") for r in rows], dtype=object)
    if "condition" not in fields or not labels.any():
        labels_or_none, condition = None, None
    elif (labels == "").any():
        raise ValueError(f"{path}: column 'condition' is empty on some rows")
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
        raise ValueError(f"{path}: column {column!r} mixes {sorted(labels)}; one value per file")
    return labels.pop() if labels else None
