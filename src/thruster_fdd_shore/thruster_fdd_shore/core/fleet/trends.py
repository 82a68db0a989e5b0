"""Trend test of a thruster's effectiveness over calendar time.

The test: a one-sided Mann-Kendall test for a decrease of the per-recording median
effectiveness (``eff_q50``) against the recordings' start times, with the tie-corrected variance
and continuity correction, and the Theil-Sen slope (median of pairwise slopes, per 30 days) as
the size of the trend. A thruster is flagged when its p-value is below ``alpha / m``, ``m`` the
number of thrusters tested (Bonferroni): with no trend anywhere and independent recordings, the
chance that any thruster of the fleet is flagged (the family-wise false-alarm rate) is at most
``alpha``. Rank-based, so a step (a blade lost) counts as a decrease as well as slow fouling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

DEFAULT_ALPHA = 0.05
"""Family-wise false-alarm rate of the fleet's trend flags."""

MIN_RECORDINGS = 6
"""Fewest recordings with an effectiveness a thruster needs to be tested."""

TEST_NAME = "one-sided Mann-Kendall (decrease), Theil-Sen slope, Bonferroni"


@dataclass(frozen=True)
class Trend:
    """The trend test of one thruster.

    Attributes
    ----------
    n : int
        Recordings tested.
    s : float
        Mann-Kendall statistic (pairs rising minus pairs falling).
    z : float
        Its standard score (continuity corrected).
    p : float
        One-sided p-value for a decrease.
    slope_per_30d : float
        Theil-Sen slope of effectiveness per 30 days.
    flagged : bool
        ``p < alpha / m``.
    """

    n: int
    s: float
    z: float
    p: float
    slope_per_30d: float
    flagged: bool


def mann_kendall(t_s: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Mann-Kendall statistic, z and one-sided p-value (decrease) of ``y`` ordered by ``t_s``.

    Parameters
    ----------
    t_s : np.ndarray, shape (n,)
        Times, s.
    y : np.ndarray, shape (n,)
        Values.

    Returns
    -------
    (float, float, float)
        ``S``, ``z`` and ``P(Z <= z)``.
    """
    order = np.argsort(t_s, kind="stable")
    y = np.asarray(y, dtype=float)[order]
    n = len(y)
    diff = np.sign(y[None, :] - y[:, None])
    s = float(np.sum(np.triu(diff, k=1)))
    _, counts = np.unique(y, return_counts=True)
    var = (n * (n - 1) * (2 * n + 5) - np.sum(counts * (counts - 1) * (2 * counts + 5))) / 18.0
    if var <= 0:
        return s, 0.0, 0.5
    z = (s - math.copysign(1.0, s)) / math.sqrt(var) if s != 0 else 0.0
    return s, z, float(norm.cdf(z))


def theil_sen(t_s: np.ndarray, y: np.ndarray) -> float:
    """Median of the pairwise slopes of ``y`` against ``t_s`` (unit of y per s)."""
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(y, dtype=float)
    i, j = np.triu_indices(len(t), k=1)
    dt = t[j] - t[i]
    keep = dt != 0
    if not keep.any():
        return 0.0
    return float(np.median((y[j] - y[i])[keep] / dt[keep]))


def find_trends(
    series: dict[str, tuple[np.ndarray, np.ndarray]], alpha: float = DEFAULT_ALPHA
) -> dict[str, Trend]:
    """Trend test of every thruster with at least ``MIN_RECORDINGS`` values.

    Parameters
    ----------
    series : dict of str to (np.ndarray, np.ndarray)
        Per thruster (``vehicle/thruster``): start times (s since the epoch) and median
        effectiveness, each shape (n,); NaN values are left out.
    alpha : float
        Family-wise false-alarm rate.
    """
    clean = {}
    for key, (t, y) in series.items():
        ok = np.isfinite(y)
        if ok.sum() >= MIN_RECORDINGS:
            clean[key] = (np.asarray(t, dtype=float)[ok], np.asarray(y, dtype=float)[ok])
    m = max(len(clean), 1)
    out = {}
    for key, (t, y) in clean.items():
        s, z, p = mann_kendall(t, y)
        slope = theil_sen(t, y) * 30 * 86400.0
        out[key] = Trend(len(y), s, z, p, slope, p < alpha / m)
    return out
