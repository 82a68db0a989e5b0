"""Trace data: the interchange format (docs/contracts.md, "Trace CSV") as a typed container."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES

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
                raise BadInputError(f"trace column {name!r} must be a 1-D numpy array")
            if len(arr) != n:
                raise BadInputError(f"trace column {name!r} has {len(arr)} samples, 't' has {n}")
        for name, arr in self.extra.items():
            if len(arr) != n:
                raise BadInputError(f"extra column {name!r} has {len(arr)} samples, 't' has {n}")
        if n > 1 and not np.all(np.diff(self.t) > 0):
            raise BadInputError("trace column 't' must be strictly increasing")
        names = set() if self.condition is None else {self.condition}
        if self.labels is not None:
            if self.condition is not None:
                raise BadInputError("give either one condition or per-sample labels, not both")
            if len(self.labels) != n:
                raise BadInputError(f"labels have {len(self.labels)} entries, 't' has {n}")
            names = set(self.labels.tolist())
        unknown = names - set(CLASS_NAMES)
        if unknown:
            raise BadInputError(
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
