"""The generic correction: a low-dimensional model of what a simulation misses, named nowhere.

A named effect must explain something this correction cannot, or as much as it does
(``engine``): otherwise a flexible effect could stand in for a difference of another kind. It is
an output correction of each channel's normalised residual, linear in smooth basis functions
fitted by least squares on the training blocks of a fold and applied to its held-out blocks:

- ``static``: piecewise-linear functions of the command (knots every 1/3) and of the measured
  speed (knots every 1/2 of its range): a smooth static curve, the guard of every move;
- ``dynamics``: the measured speed's rate of change and the command minus its 1 s average;
- ``voltage``: the measured current and the slow supply (``measure.supply_voltage``): never a
  sample's own measured voltage, whose noise the correction would otherwise fit.

The other two groups only say what kind of mismatch a structured rest is.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d

from thruster_fdd_shore.core.discrepancy.measure import Measured, supply_voltage

GROUPS = ("static", "dynamics", "voltage")
"""Basis groups; ``static`` is the guard, the others classify a rest."""

KINDS = {
    "static": "static curve (a smooth map of command or speed)",
    "dynamics": "dynamics (how the response follows a changing command)",
    "voltage": "voltage (the response to current and supply)",
}
"""Plain-language name of each group's kind of mismatch."""


def _hats(x: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Piecewise-linear hat functions of ``x`` on ``knots``, shape (n, len(knots))."""
    eye = np.eye(len(knots))
    return np.stack([np.interp(x, knots, eye[k]) for k in range(len(knots))], axis=1)


def basis(data: Measured, group: str = "static") -> np.ndarray:
    """The basis of ``group`` (one of ``GROUPS``), with a constant, shape (n, q), columns of unit
    RMS."""
    n = len(data.t)
    if group == "static":
        top = max(float(np.max(np.abs(data.rpm))), 1.0)
        cols = [_hats(data.command, np.linspace(-1.0, 1.0, 7))]
        cols.append(_hats(np.clip(data.rpm / top, -1.0, 1.0), np.linspace(-1.0, 1.0, 5))[:, 1:])
    elif group == "dynamics":
        dt = max(float(np.median(np.diff(data.t))), 1e-6)
        width = max(3, round(1.0 / dt))
        cols = [
            np.gradient(data.rpm, data.t)[:, None],
            (data.command - uniform_filter1d(data.command, width, mode="nearest"))[:, None],
            np.ones((n, 1)),
        ]
    elif group == "voltage":
        supply = supply_voltage(data, 0.0)
        cols = [data.current[:, None], (supply - supply.mean())[:, None], np.ones((n, 1))]
    else:
        raise ValueError(f"unknown group {group!r}; expected one of {GROUPS}")
    phi = np.concatenate(cols, axis=1)
    rms = np.sqrt(np.mean(phi**2, axis=0))
    return phi / np.where(rms > 0.0, rms, 1.0)


def corrected(
    r: np.ndarray, seen: np.ndarray, train: np.ndarray, test: np.ndarray, phi: np.ndarray
) -> np.ndarray:
    """Residuals on ``test`` after the correction fitted on ``train``.

    Parameters
    ----------
    r : np.ndarray, shape (c, n)
        Normalised residuals (noise standard deviations) of each channel.
    seen : np.ndarray of bool, shape (c, n)
        Samples each channel's residual says something about (not censored).
    train, test : np.ndarray of bool, shape (n,)
        Samples the correction is fitted on and applied to.
    phi : np.ndarray, shape (n, q)
        The basis (``basis``).

    Returns
    -------
    np.ndarray, shape (c, n)
        ``r`` with ``phi @ a_c`` subtracted on ``test`` (``a_c`` least squares on ``train``);
        other samples unchanged.
    """
    out = np.array(r, copy=True)
    for c in range(r.shape[0]):
        rows = train & seen[c]
        if rows.sum() <= phi.shape[1]:
            continue
        coef, *_ = np.linalg.lstsq(phi[rows], r[c, rows], rcond=1e-8)
        out[c, test] = r[c, test] - phi[test] @ coef
    return out
