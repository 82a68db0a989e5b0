"""What a nominal model is, without torch: its signals, the paper's six architectures, their
hyperparameters (``ModelSpec``) and the IQR scaling every model carries inside itself.

Every model maps the inputs ``command`` (normalised, -1..1) and ``voltage`` (V) to the outputs
``rpm`` and ``current`` (A), in IQR-scaled units inside the network. Regressors at sample ``k``
use samples ``k-1, k-2, ...`` only (strictly the past: the prediction of sample ``k`` never sees
anything measured at ``k``).

- ``mlp``: static MLP of the last input sample.
- ``mlp_tdd``: Hammerstein-Wiener style MLP: learnable deadband on the command, a tapped delay
  line of ``input_lags`` input samples, MLP.
- ``narx`` / ``narx_deadband``: MLP (plus a linear skip) of ``input_lags`` past inputs and
  ``output_lags`` past outputs; the deadband variant puts a learnable deadband on the command.
  Series-parallel: past outputs are measured; parallel: past outputs are the model's own
  predictions (free run after an initialisation window of measured samples).
- ``lstm`` / ``gru``: recurrent networks over the input sequence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from thruster_fdd.core.artifact import scaling_entries

INPUTS: tuple[str, ...] = ("command", "voltage")
"""Model inputs, in order: normalised command (-1..1), bus voltage (V)."""


OUTPUTS: tuple[str, ...] = ("rpm", "current")
"""Model outputs, in order: shaft speed (rpm), bus current (A)."""


MODES: tuple[str, ...] = ("series-parallel", "parallel")
"""NARX configurations: one step ahead from measured past outputs, or free run."""


ARCHITECTURES: tuple[str, ...] = ("mlp", "mlp_tdd", "narx", "narx_deadband", "lstm", "gru")
"""The six regressors of the paper's Table 1."""


NARX_ARCHITECTURES: tuple[str, ...] = ("narx", "narx_deadband")


MIN_SCALE: dict[str, float] = {"command": 0.1, "voltage": 1.0, "rpm": 100.0, "current": 0.5}
"""Floor of each signal's IQR, in its unit: a signal nearly constant in the training data (the
supply voltage of a single-voltage run) must not be blown up into noise of unit size."""


@dataclass(frozen=True)
class IqrScaler:
    """Per-signal robust scaling ``(x - median) / max(IQR, floor)``.

    Attributes
    ----------
    names : tuple of str
        Signal names, one per column.
    center : tuple of float
        Median of each signal in its unit.
    scale : tuple of float
        Interquartile range of each signal (floored by ``MIN_SCALE``), in its unit.
    """

    names: tuple[str, ...]
    center: tuple[float, ...]
    scale: tuple[float, ...]

    def __post_init__(self) -> None:
        if not (len(self.names) == len(self.center) == len(self.scale)):
            raise ValueError("IqrScaler: names, center and scale must have equal lengths")
        if not all(math.isfinite(c) for c in self.center):
            raise ValueError(f"IqrScaler: center must be finite, got {self.center}")
        if not all(math.isfinite(s) and s > 0 for s in self.scale):
            raise ValueError(f"IqrScaler: scale must be finite and > 0, got {self.scale}")

    @classmethod
    def fit(cls, names: tuple[str, ...], x: np.ndarray) -> IqrScaler:
        """Fit on data ``x`` of shape (n, len(names)); NaN rows are ignored."""
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != len(names) or len(x) == 0:
            raise ValueError(f"IqrScaler.fit: expected shape (n, {len(names)}), got {x.shape}")
        q25, q50, q75 = np.nanpercentile(x, [25.0, 50.0, 75.0], axis=0)
        scale = [
            max(float(hi - lo), MIN_SCALE.get(n, 1e-9))
            for n, lo, hi in zip(names, q25, q75, strict=True)
        ]
        return cls(tuple(names), tuple(float(c) for c in q50), tuple(scale))

    def transform(self, x: np.ndarray) -> np.ndarray:
        """Scale ``x`` of shape (..., len(names)) from signal units to scaled units."""
        return (np.asarray(x, dtype=float) - np.asarray(self.center)) / np.asarray(self.scale)

    def inverse(self, z: np.ndarray) -> np.ndarray:
        """Map scaled ``z`` of shape (..., len(names)) back to signal units."""
        return np.asarray(z, dtype=float) * np.asarray(self.scale) + np.asarray(self.center)

    def to_dict(self) -> dict[str, dict[str, float]]:
        """``{signal: {"center": median, "scale": IQR}}``, the model card's scaling entries."""
        return scaling_entries(self.names, np.asarray(self.center), np.asarray(self.scale))

    @classmethod
    def from_dict(cls, names: tuple[str, ...], d: dict[str, Any]) -> IqrScaler:
        """Inverse of ``to_dict`` for the given signal order; ValueError if a signal is missing."""
        missing = [n for n in names if n not in d]
        if missing:
            raise ValueError(f"scaling lacks signal(s) {', '.join(missing)}")
        return cls(
            tuple(names),
            tuple(float(d[n]["center"]) for n in names),
            tuple(float(d[n]["scale"]) for n in names),
        )


@dataclass(frozen=True)
class ModelSpec:
    """Hyperparameters of one regressor.

    Attributes
    ----------
    architecture : str
        One of ``ARCHITECTURES``.
    hidden : tuple of int
        Hidden layer sizes (MLP, NARX) or ``(state size,)`` (LSTM, GRU).
    input_lags : int
        Past input samples seen (``mlp``: 1; recurrent: 1, the state holds the rest).
    output_lags : int
        Past output samples seen (NARX only; 0 otherwise).
    feedback : tuple of str
        Which outputs' past values enter the regressor (NARX only), a subset of ``OUTPUTS`` in
        order. The bus current is quasi-static in duty and speed, so a NARX without its own
        current feedback extrapolates better in free run (docs/nominal_model.md).
    """

    architecture: str
    hidden: tuple[int, ...] = (32,)
    input_lags: int = 10
    output_lags: int = 2
    feedback: tuple[str, ...] = OUTPUTS

    def __post_init__(self) -> None:
        if self.architecture not in ARCHITECTURES:
            raise ValueError(
                f"unknown architecture {self.architecture!r}; expected one of "
                f"{', '.join(ARCHITECTURES)}"
            )
        if not self.hidden or any(h < 1 for h in self.hidden):
            raise ValueError(f"hidden sizes must be >= 1, got {self.hidden}")
        if self.input_lags < 1:
            raise ValueError(f"input_lags must be >= 1, got {self.input_lags}")
        is_narx = self.architecture in NARX_ARCHITECTURES
        if is_narx and self.output_lags < 1:
            raise ValueError(f"a NARX needs output_lags >= 1, got {self.output_lags}")
        if is_narx and (not self.feedback or any(f not in OUTPUTS for f in self.feedback)):
            raise ValueError(
                f"feedback must be a non-empty subset of {OUTPUTS}, got {self.feedback}"
            )
        if is_narx and tuple(f for f in OUTPUTS if f in self.feedback) != self.feedback:
            raise ValueError(f"feedback must list outputs in the order {OUTPUTS}")
        if not is_narx and self.output_lags != 0:
            raise ValueError(f"{self.architecture} has no output feedback: output_lags must be 0")
        if self.architecture in ("mlp", "lstm", "gru") and self.input_lags != 1:
            raise ValueError(f"{self.architecture} takes input_lags = 1")
        if self.architecture in ("lstm", "gru") and len(self.hidden) != 1:
            raise ValueError(f"{self.architecture} takes one state size, got {self.hidden}")

    @property
    def is_narx(self) -> bool:
        """True for the NARX regressors (output feedback)."""
        return self.architecture in NARX_ARCHITECTURES

    @property
    def is_recurrent(self) -> bool:
        """True for LSTM and GRU."""
        return self.architecture in ("lstm", "gru")

    @property
    def has_deadband(self) -> bool:
        """True when the command passes a learnable deadband first."""
        return self.architecture in ("mlp_tdd", "narx_deadband")

    @property
    def feedback_index(self) -> list[int]:
        """Column indices (into ``OUTPUTS``) of the fed-back outputs; empty without feedback."""
        return [OUTPUTS.index(f) for f in self.feedback] if self.output_lags else []

    @property
    def n_regressors(self) -> int:
        """Length of the flattened regressor vector."""
        return 2 * self.input_lags + len(self.feedback_index) * self.output_lags

    @property
    def warmup(self) -> int:
        """Samples needed before the first prediction: ``max(input_lags, output_lags)``."""
        return max(self.input_lags, self.output_lags)
