"""Scores of a classifier: confusion matrices, balanced accuracy, NLL and calibration error."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def confusion(y_true: np.ndarray, y_pred: np.ndarray, labels: Sequence[str]) -> np.ndarray:
    """Counts (len(labels), len(labels) + 1): rows true class, columns predicted class then
    ``unknown`` (any prediction not in ``labels``)."""
    index = {c: i for i, c in enumerate(labels)}
    m = np.zeros((len(labels), len(labels) + 1), dtype=int)
    for t, p in zip(y_true.tolist(), y_pred.tolist(), strict=True):
        m[index[t], index.get(p, len(labels))] += 1
    return m


def normalise_rows(m: np.ndarray) -> np.ndarray:
    """Row-normalised confusion matrix (each true class sums to 1; empty rows stay 0)."""
    s = m.sum(axis=1, keepdims=True)
    return np.divide(m, s, out=np.zeros(m.shape, dtype=float), where=s > 0)


def balanced_accuracy(m: np.ndarray) -> float:
    """Mean per-class recall of a confusion count matrix (rows with samples only)."""
    rows = m.sum(axis=1) > 0
    return float(np.mean(np.diag(m[:, : m.shape[0]])[rows] / m.sum(axis=1)[rows]))


def classification_metrics(probs: np.ndarray, y: np.ndarray, n_classes: int) -> dict[str, float]:
    """Accuracy, balanced accuracy, NLL and expected calibration error (10 bins) of (m, C)."""
    pred = probs.argmax(axis=1)
    recalls = [float(np.mean(pred[y == c] == c)) for c in range(n_classes) if np.any(y == c)]
    return {
        "accuracy": float(np.mean(pred == y)),
        "balanced_accuracy": float(np.mean(recalls)),
        "nll": float(-np.mean(np.log(probs[np.arange(len(y)), y] + 1e-12))),
        "ece": expected_calibration_error(probs, y),
        "windows": len(y),
    }


def reliability(probs: np.ndarray, y: np.ndarray, bins: int = 10) -> list[dict[str, float]]:
    """Reliability table of probabilities (m, C) against labels (m,): per non-empty bin of the
    top-class probability (equal widths on 0..1) its mean confidence, accuracy and share."""
    pred = probs.argmax(axis=1)
    conf = probs.max(axis=1)
    index = np.minimum((conf * bins).astype(int), bins - 1)
    return [
        {
            "confidence": float(conf[index == b].mean()),
            "accuracy": float(np.mean(pred[index == b] == y[index == b])),
            "share": float(np.mean(index == b)),
        }
        for b in range(bins)
        if np.any(index == b)
    ]


def expected_calibration_error(probs: np.ndarray, y: np.ndarray, bins: int = 10) -> float:
    """Expected calibration error: |accuracy - confidence| of ``reliability``'s bins, weighted
    by their share of windows."""
    return float(
        sum(abs(r["accuracy"] - r["confidence"]) * r["share"] for r in reliability(probs, y, bins))
    )
