"""Reference load curves of a thruster type, as an exported folder the health node reads.

The effectiveness estimate (``diagnosis.effectiveness``) compares a thruster's measured power
with the power a healthy or damaged propeller of its type draws at the same speed. Those curves
come from the thruster type's physics at steady state; they are computed ashore
(``thruster-fdd reference``, ``thruster_fdd_shore.core.reference``) and stored as a folder that
the vehicle only reads: ``model_card.json`` (kind ``reference``) and ``weights.npz`` with the
arrays below, every file checked by its SHA-256 as for the other models (docs/contracts.md,
"Exported model").

Arrays of ``weights.npz`` (B voltage bins, F = 2 families, D = 2 directions, K severities,
U command magnitudes, S speed points):

| name | shape | unit |
|---|---|---|
| ``voltages`` | (B,) | V, uniform step ``VOLTAGE_STEP_V`` |
| ``severities`` | (K,) | blades lost / fouling level, step ``SEVERITY_STEP`` from 0 |
| ``commands`` | (U,) | command magnitude 0..1, uniform |
| ``thrust`` | (B, F, D, K, U) | N |
| ``speeds`` | (B, F, D, S) | rad/s, uniform from 0 |
| ``power`` | (B, F, D, K, S) | W |
| ``informative_speed`` | (B, F, D) | rad/s |
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thruster_fdd.core.artifact import ModelCard, load_weights, read_card
from thruster_fdd.core.errors import ModelMismatchError

FAULT_FAMILIES: tuple[str, ...] = ("blades", "fouling")
"""Fault families with a continuous severity (the order of the arrays' F axis)."""

MAX_SEVERITY = 2.0
"""Largest severity of either family: two blades lost, or twice the ``biofouling`` class."""

SEVERITY_STEP = 0.1
"""Spacing of the severity grid of the reference curves."""

VOLTAGE_STEP_V = 0.5
"""Spacing of the supply-voltage bins of the reference curves, V."""

MIN_SPEED_FRACTION = 0.25
"""A sample informs the severity when the rotor turns faster than this share of the healthy top
speed at its supply (slow rotation: power is mostly losses, the load tells little)."""

REFERENCE_KIND = "reference"
"""The ``kind`` of a reference folder's card."""

ARRAYS: dict[str, int] = {
    "voltages": 1,
    "severities": 1,
    "commands": 1,
    "thrust": 5,
    "speeds": 4,
    "power": 5,
    "informative_speed": 3,
}
"""The arrays of a reference folder and their number of dimensions."""


@dataclass(frozen=True)
class FamilyCurves:
    """Steady-state reference of one fault family at one supply voltage, one direction.

    Attributes
    ----------
    severities : np.ndarray, shape (K,)
        Severity grid, 0 first (healthy).
    commands : np.ndarray, shape (U,)
        Command magnitudes of ``thrust``, uniform on 0..1.
    thrust : np.ndarray, shape (K, U)
        Thrust magnitude per severity at ``commands``, N.
    speeds : np.ndarray, shape (S,)
        Speed grid of ``power``, rad/s, uniform from 0.
    power : np.ndarray, shape (K, S)
        Electrical power ``V I`` per severity at those speeds, W (held at the last value beyond
        the speed a severity reaches).
    informative_speed : float
        ``MIN_SPEED_FRACTION`` of the healthy top speed, rad/s.
    """

    severities: np.ndarray
    commands: np.ndarray
    thrust: np.ndarray
    speeds: np.ndarray
    power: np.ndarray
    informative_speed: float

    def power_at(self, speed: float) -> np.ndarray:
        """Power of every severity at ``speed`` rad/s, W, shape (K,) (linear interpolation)."""
        step = self.speeds[1]
        x = min(max(speed / step, 0.0), len(self.speeds) - 1.000001)
        i = int(x)
        f = x - i
        return self.power[:, i] * (1.0 - f) + self.power[:, i + 1] * f

    def thrust_at(self, magnitudes: np.ndarray) -> np.ndarray:
        """Thrust of every severity at command ``magnitudes`` (n,), N, shape (K, n)."""
        n = len(self.commands)
        x = np.clip(magnitudes, 0.0, 1.0) * (n - 1)
        i = np.minimum(x.astype(int), n - 2)
        f = x - i
        return self.thrust[:, i] * (1.0 - f) + self.thrust[:, i + 1] * f


@dataclass(frozen=True, kw_only=True)
class ReferenceCard(ModelCard):
    """The card of a reference folder (``ModelCard`` fields; ``extra`` holds ``thruster_type``,
    the name of the configuration the curves were computed from, and ``config_digest``, the
    SHA-256 of that configuration)."""


class ThrustReference:
    """Reference curves of a thruster type on a grid of supply-voltage bins.

    Parameters
    ----------
    arrays : dict of str to np.ndarray
        The arrays of the module docstring's table.
    name : str
        What the curves describe (shown in logs and on ``/diagnostics``).

    Raises
    ------
    ModelMismatchError
        If an array is missing, of the wrong shape, non-finite, or a grid is not uniform.
    """

    def __init__(self, arrays: dict[str, np.ndarray], name: str = "reference") -> None:
        missing = sorted(set(ARRAYS) - set(arrays))
        if missing:
            raise ModelMismatchError(f"{name}: reference lacks {', '.join(missing)}")
        a = {k: np.asarray(arrays[k], dtype=np.float64) for k in ARRAYS}
        for key, ndim in ARRAYS.items():
            if a[key].ndim != ndim or not np.all(np.isfinite(a[key])):
                raise ModelMismatchError(f"{name}: reference array {key} is not finite {ndim}-D")
        b, k, u = len(a["voltages"]), len(a["severities"]), len(a["commands"])
        s = a["speeds"].shape[-1]
        n_fam = len(FAULT_FAMILIES)
        expected = {
            "thrust": (b, n_fam, 2, k, u),
            "speeds": (b, n_fam, 2, s),
            "power": (b, n_fam, 2, k, s),
            "informative_speed": (b, n_fam, 2),
        }
        for key, shape in expected.items():
            if a[key].shape != shape:
                raise ModelMismatchError(
                    f"{name}: reference array {key} has shape {a[key].shape}, expected {shape}"
                )
        if b < 1 or k < 2 or u < 2 or s < 2:
            raise ModelMismatchError(f"{name}: reference grids too small ({b}, {k}, {u}, {s})")
        for key in ("voltages", "severities", "commands"):
            if len(a[key]) > 1 and not np.allclose(np.diff(a[key]), a[key][1] - a[key][0]):
                raise ModelMismatchError(f"{name}: reference grid {key} is not uniform")
        if a["severities"][0] != 0.0 or np.any(np.diff(a["severities"]) <= 0):
            raise ModelMismatchError(f"{name}: reference severities must rise from 0")
        self.name = name
        self.voltages = a["voltages"]
        self.severities = a["severities"]
        self._arrays = a
        self._curves: dict[tuple[int, int, int], FamilyCurves] = {}

    @classmethod
    def load(cls, folder: str | Path) -> ThrustReference:
        """Read an exported reference folder (every file checked by its digest).

        Raises
        ------
        ModelMismatchError
            Naming the file and what is wrong.
        """
        card = read_card(folder, ReferenceCard, REFERENCE_KIND)
        return cls(load_weights(folder, card), name=card.model_id)

    def voltage_bin(self, voltage: float) -> int:
        """Index of the stored supply-voltage bin nearest to ``voltage`` V (clamped)."""
        v0 = float(self.voltages[0])
        step = float(self.voltages[1] - v0) if len(self.voltages) > 1 else 1.0
        return int(np.clip(round((voltage - v0) / step), 0, len(self.voltages) - 1))

    def covers(self, voltage: float) -> bool:
        """Whether ``voltage`` V lies within half a bin of the stored range."""
        half = 0.5 * VOLTAGE_STEP_V
        return float(self.voltages[0]) - half <= voltage <= float(self.voltages[-1]) + half

    def curves(self, family: str, voltage: float, reverse: bool) -> FamilyCurves:
        """The curves of ``family`` at the bin of ``voltage`` V, forward or ``reverse``."""
        key = (self.voltage_bin(voltage), FAULT_FAMILIES.index(family), int(reverse))
        curves = self._curves.get(key)
        if curves is None:
            a = self._arrays
            curves = self._curves[key] = FamilyCurves(
                severities=self.severities,
                commands=a["commands"],
                thrust=a["thrust"][key],
                speeds=a["speeds"][key],
                power=a["power"][key],
                informative_speed=float(a["informative_speed"][key]),
            )
        return curves
