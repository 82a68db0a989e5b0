"""The operating region a classifier was trained on, and whether a window lies inside it.

A classifier's probabilities mean something only at operating points like those of its training
windows: a healthy thruster cruising at a constant command that the training never held can
look like a broken blade with certainty. Each window is therefore placed at an operating point
(``OPERATING_POINT``: what the residuals of a healthy thruster depend on besides its health: the
command level and direction, how fast the command changes within the window, and the supply),
measured in the physical units of ``RESOLUTION`` (the step at which two operating points count as
different). A window is *covered* when its distance to the ``K``-th nearest training window is
at most the card's threshold, which training sets at a quantile of the same distance for
held-out windows of other units (``coverage_quantile``): a covered window is as close to the
training data as the held-out windows the probabilities were calibrated on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

OPERATING_POINT: tuple[str, ...] = (
    "command_mean",
    "command_abs_mean",
    "command_std",
    "voltage_mean",
)
"""Coordinates of a window's operating point: mean command (-1..1), mean |command|, standard
deviation of the command within the window, mean bus voltage (V)."""

RESOLUTION: dict[str, float] = {
    "command_mean": 0.1,
    "command_abs_mean": 0.1,
    "command_std": 0.05,
    "voltage_mean": 0.5,
}
"""Default unit of each coordinate: operating points this far apart in one coordinate are one
unit apart (command steps of 0.1, command variation of 0.05, 0.5 V of supply)."""

K = 5
"""The distance of a window to the training data is to its K-th nearest training window (one
lone training window does not make a region)."""

MAX_POINTS = 4000
"""Most training operating points a card keeps (a uniform subsample beyond)."""


def operating_point(window: np.ndarray) -> np.ndarray:
    """The operating point (``OPERATING_POINT``) of a window of samples (n, 6) in the columns
    of ``features.WINDOW_SIGNALS`` (command first, voltage second): shape (4,). Commands count
    within -1..1 and voltages within 0..1000 V, so wild samples stay finite (and uncovered)."""
    command = np.clip(window[:, 0], -1.0, 1.0)
    return np.array(
        [
            float(command.mean()),
            float(np.abs(command).mean()),
            float(command.std()),
            float(np.clip(window[:, 1], 0.0, 1000.0).mean()),
        ]
    )


@dataclass(frozen=True)
class Coverage:
    """The training region of a classifier.

    Attributes
    ----------
    points : np.ndarray, shape (N, 4)
        Operating points of training windows, in ``resolution`` units.
    resolution : np.ndarray, shape (4,)
        Physical size of one unit of each coordinate (``RESOLUTION`` order).
    threshold : float
        Largest K-th-nearest distance of a covered window, in resolution units.
    """

    points: np.ndarray
    resolution: np.ndarray
    threshold: float

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (B,) of operating points (B, 4) to their K-th nearest training point, in
        resolution units."""
        scaled = np.atleast_2d(np.asarray(points, dtype=float)) / self.resolution
        return _kth_distance(scaled, self.points, min(K, len(self.points)))

    def covers(self, point: np.ndarray) -> tuple[bool, float]:
        """Whether one operating point (4,) is covered, and its distance."""
        d = float(self.distance(point)[0])
        return d <= self.threshold, d

    def summary(self) -> dict[str, list[float]]:
        """Per coordinate the 1st and 99th percentile of the training operating points, in
        physical units (what ``train`` prints and the card shows)."""
        raw = self.points * self.resolution
        lo, hi = np.percentile(raw, [1.0, 99.0], axis=0)
        return {
            name: [round(float(a), 3), round(float(b), 3)]
            for name, a, b in zip(OPERATING_POINT, lo, hi, strict=True)
        }


@njit(cache=True)
def _kth_distance(x: np.ndarray, points: np.ndarray, k: int) -> np.ndarray:
    """Euclidean distance (B,) of each row of ``x`` (B, D) to its k-th nearest row of
    ``points`` (N, D)."""
    out = np.empty(x.shape[0])
    best = np.empty(k)
    for r in range(x.shape[0]):
        best[:] = np.inf
        for j in range(points.shape[0]):
            total = 0.0
            for d in range(x.shape[1]):
                diff = x[r, d] - points[j, d]
                total += diff * diff
            if total < best[k - 1]:
                i = k - 1
                while i > 0 and best[i - 1] > total:
                    best[i] = best[i - 1]
                    i -= 1
                best[i] = total
        out[r] = np.sqrt(best[k - 1])
    return out
