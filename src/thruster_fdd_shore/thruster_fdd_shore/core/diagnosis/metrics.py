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
    conf = probs.max(axis=1)
    bins = np.minimum((conf * 10).astype(int), 9)
    ece = sum(
        abs(float(np.mean(pred[bins == b] == y[bins == b])) - float(conf[bins == b].mean()))
        * float(np.mean(bins == b))
        for b in range(10)
        if np.any(bins == b)
    )
    return {
        "accuracy": float(np.mean(pred == y)),
        "balanced_accuracy": float(np.mean(recalls)),
        "nll": float(-np.mean(np.log(probs[np.arange(len(y)), y] + 1e-12))),
        "ece": float(ece),
        "windows": len(y),
    }
