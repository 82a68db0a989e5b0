"""Trace data: the interchange format (docs/contracts.md, "Trace CSV") as a typed container."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from thruster_fdd.core.errors import BadInputError, PartialInputWarning
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


class TraceWarning(PartialInputWarning):
    """A trace was read with some samples left out; the text says which and how many."""


MAX_STEP_S = 5.0
"""Median time step above which ``t`` is taken to be in the wrong unit (ms or µs): the models
run at 0.1 s, and 5 s is a millisecond trace at 200 Hz."""


MAX_MEDIAN_VOLTAGE_V = 100.0
"""Median bus voltage above which ``voltage`` is taken to be in mV (thrusters run <= 60 V)."""


MAX_CURRENT_A = 200.0
"""99th percentile of |current| above which ``current`` is taken to be in mA."""


MAX_RPM = 30_000.0
"""99th percentile of |rpm| above which ``rpm`` is taken to be eRPM or another unit."""


def finite_rows(columns: dict[str, np.ndarray], source: str) -> dict[str, np.ndarray]:
    """The samples whose every numeric column is finite; one TraceWarning says how many were
    left out and the first of them.

    Parameters
    ----------
    columns : dict of str to np.ndarray
        Numeric columns, each shape (n,).
    source : str
        What the columns were read from (a file), for the messages.

    Returns
    -------
    dict of str to np.ndarray
        The same columns, each shape (m,), m <= n.

    Raises
    ------
    BadInputError
        If no sample is left.
    """
    n = len(next(iter(columns.values()))) if columns else 0
    keep = np.ones(n, dtype=bool)
    for values in columns.values():
        keep &= np.isfinite(values)
    dropped = int(n - keep.sum())
    if dropped == 0:
        return columns
    bad = [name for name, values in columns.items() if not np.all(np.isfinite(values))]
    first = int(np.argmin(keep))
    if dropped == n:
        raise BadInputError(f"{source}: every sample has a non-finite value (in {', '.join(bad)})")
    warnings.warn(
        TraceWarning(
            f"{source}: left out {dropped} of {n} samples with a non-finite value in "
            f"{', '.join(bad)} (the first is sample {first})"
        ),
        stacklevel=3,
    )
    return {name: values[keep] for name, values in columns.items()}


def check_time(t: np.ndarray, source: str) -> None:
    """BadInputError naming the sample unless ``t`` (s, shape (n,)) strictly increases."""
    steps = np.diff(t)
    if np.any(steps <= 0):
        i = int(np.argmax(steps <= 0)) + 1
        raise BadInputError(
            f"{source}: column 't' must strictly increase; sample {i} is {t[i]:g} s after "
            f"{t[i - 1]:g} s"
        )


def check_units(trace: Trace, source: str) -> None:
    """BadInputError with a hint when a column is plausibly in the wrong unit.

    Checks that ``command`` lies within -1..1 (a pulse width in µs or a percentage is named),
    that the median time step is at most ``MAX_STEP_S`` (ms or µs named), and that voltage,
    current and rpm are not a thousand times too large (mV, mA) or eRPM.

    Parameters
    ----------
    trace : Trace
        The trace, finite values.
    source : str
        What it was read from, for the message.
    """
    command = np.abs(trace.command)
    if command.size and float(command.max()) > 1.001:
        peak = float(command.max())
        median = float(np.median(trace.command))
        if 800.0 <= median <= 2200.0:
            hint = "it looks like a pulse width in µs: command = (pwm_us - 1500) / 400"
        elif peak <= 100.0:
            hint = "if it is in percent, divide by 100"
        else:
            hint = "the command is normalised to -1..1"
        raise BadInputError(f"{source}: column 'command' reaches {peak:g}, outside -1..1; {hint}")
    if len(trace) > 1:
        step = float(np.median(np.diff(trace.t)))
        if step > MAX_STEP_S:
            unit = "µs (divide by 1e6)" if step > 5_000.0 else "ms (divide by 1000)"
            raise BadInputError(
                f"{source}: column 't' steps by {step:g} per sample (median); times are in "
                f"seconds and this looks like {unit}"
            )
    checks = (
        ("voltage", "median", np.median(np.abs(trace.voltage)), MAX_MEDIAN_VOLTAGE_V, "V", "mV"),
        ("current", "99th percentile", np.percentile(np.abs(trace.current), 99), MAX_CURRENT_A,
         "A", "mA"),
        ("rpm", "99th percentile", np.percentile(np.abs(trace.rpm), 99), MAX_RPM, "rpm",
         "eRPM (rpm x pole pairs)"),
    )  # fmt: skip
    for name, statistic, value, limit, unit, guess in checks:
        if value > limit:
            raise BadInputError(
                f"{source}: column {name!r} has a {statistic} of {value:g}, above {limit:g} "
                f"{unit}; is it in {guess}?"
            )
