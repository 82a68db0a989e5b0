"""An exported window classifier loaded for use: calibrated probabilities and the distance to the
nearest class, evaluated by compiled kernels checked against the exported program at load.

The classifier is an MLP on standardised window features (``diagnosis.training.FeatureMLP``),
exported as a ``torch.export`` program (``model.pt2``) with ``model_card.json``. Probabilities are
calibrated by temperature scaling on held-out windows. A window is answered ``"unknown"`` when its
calibrated top probability is under ``unknown_threshold`` or its features are far from every
class: the distance is the RMS over features of ``(z - mean_c) / std_c`` (z the standardised
features, mean/std per class from the training windows), its threshold set on held-out windows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit

from thruster_fdd.core.artifact import CARD_FILE, WEIGHTS_FILE, ModelCard, load_weights, read_card
from thruster_fdd.core.diagnosis.coverage import OPERATING_POINT, Coverage
from thruster_fdd.core.diagnosis.features import FEATURE_NAMES, WINDOW_SIGNALS, window_features
from thruster_fdd.core.errors import ModelMismatchError
from thruster_fdd.core.labels import CLASS_NAMES

KIND = "classifier"
"""``model_card.json`` kind of an exported classifier."""


Z_CLIP = 10.0
"""Standardised features are clipped to +-Z_CLIP inside the network (wild inputs stay finite)."""

P_MIN = 1e-6
"""Probabilities are clipped to [P_MIN, 1 - P_MIN]: calibration on held-out units supports no
more certainty than that."""

TEMPERATURE_RANGE = (0.05, 20.0)
"""Temperatures a card may carry (outside: the calibration failed)."""

COVERAGE_ARRAY = "coverage_points"
"""Name of the training operating points (N, 4) in ``weights.npz``."""


@dataclass(frozen=True, kw_only=True)
class ClassifierCard(ModelCard):
    """The card of an exported window classifier: ``ModelCard``'s fields with these meanings,
    plus the fields of a window decision.

    Attributes
    ----------
    inputs : tuple of str
        Per-sample signals of a window (``WINDOW_SIGNALS``).
    outputs, class_names : tuple of str
        The six classes (``labels.CLASS_NAMES``), in network output order.
    scaling : dict
        ``{feature: {"center": median, "scale": IQR}}`` in the feature's unit.
    sample_time_s : float
        Sample time of a window's samples (the nominal model's), s.
    lookbacks : dict
        ``{"window_samples": int}``: samples per window.
    architecture : str
        ``"mlp"`` (ReLU).
    features : tuple of str
        Network input, in order (``FEATURE_NAMES``).
    feature_fill : dict
        ``{feature: float}``: training median that replaces an undefined (NaN) feature.
    window_s : float
        Window length, s.
    nominal_model_id : str
        ``model_id`` of the nominal model whose residuals the features were made with.
    temperature : float
        Softmax temperature from calibration (probabilities = softmax(logits / temperature)).
    unknown : dict
        ``{"probability_threshold", "distance_threshold", "class_mean", "class_std"}``: a window
        is unknown below the first or beyond the second; class mean/std are lists (C, F) in
        standardised units.
    coverage : dict
        ``{"coordinates", "resolution", "threshold", "quantile", "summary", "evidence_floor"}``:
        the operating region of the training windows (``diagnosis.coverage``; the points
        themselves are the ``coverage_points`` array of the weights file) and the mean
        |command| from which it gives evidence (``evidence_floor.min_command_abs``; None: from
        none; absent in cards made before it: from 0).
    calibration : dict
        How the probabilities were calibrated: held-out ``units``, ``windows``, the expected
        calibration error ``ece`` before and after temperature scaling.
    """

    features: tuple[str, ...]
    feature_fill: dict[str, float]
    window_s: float
    nominal_model_id: str
    temperature: float
    unknown: dict[str, Any]
    coverage: dict[str, Any]
    calibration: dict[str, Any]


def read_classifier_card(model_dir: str | Path) -> ClassifierCard:
    """Read and check ``model_dir/model_card.json`` against what this code expects.

    Raises
    ------
    ModelMismatchError
        Naming the file and what is wrong or differs: missing, not JSON, a missing or mistyped
        field, another kind, class names or features other than this code's, inconsistent
        sizes.
    """
    card = read_card(model_dir, ClassifierCard, KIND)
    path = Path(model_dir) / CARD_FILE
    expected: dict[str, tuple[str, ...]] = {
        "class_names": CLASS_NAMES,
        "outputs": CLASS_NAMES,
        "features": FEATURE_NAMES,
        "inputs": WINDOW_SIGNALS,
    }
    for key, want in expected.items():
        if getattr(card, key) != want:
            raise ModelMismatchError(
                f"{path}: {key} are {list(getattr(card, key))}, expected {list(want)}"
            )
    try:
        card.scaling_of(FEATURE_NAMES)
        fill = [card.feature_fill[f] for f in FEATURE_NAMES]
        mean = np.asarray(card.unknown["class_mean"], dtype=float)
        std = np.asarray(card.unknown["class_std"], dtype=float)
        p_thr = float(card.unknown["probability_threshold"])
        d_thr = float(card.unknown["distance_threshold"])
        window_samples = card.lookbacks["window_samples"]
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelMismatchError(f"{path}: malformed field ({type(exc).__name__}: {exc})") from exc
    shape = (len(CLASS_NAMES), len(FEATURE_NAMES))
    if mean.shape != shape or std.shape != shape or not np.all(std > 0):
        raise ModelMismatchError(f"{path}: unknown.class_mean/class_std must be {shape}, std > 0")
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(std)) and np.all(np.isfinite(fill))):
        raise ModelMismatchError(f"{path}: non-finite class statistics or feature fill")
    if not (0.0 <= p_thr <= 1.0 and 0 < d_thr < math.inf):
        raise ModelMismatchError(f"{path}: unknown thresholds out of range ({p_thr}, {d_thr})")
    if not (0 < card.sample_time_s <= 10.0 and 0 < card.window_s <= 600.0):
        raise ModelMismatchError(f"{path}: sample_time_s must be in (0, 10], window_s (0, 600]")
    lo, hi = TEMPERATURE_RANGE
    if not lo <= card.temperature <= hi:
        raise ModelMismatchError(f"{path}: temperature {card.temperature} outside [{lo}, {hi}]")
    if not (isinstance(window_samples, int) and 4 <= window_samples <= 100_000):
        raise ModelMismatchError(f"{path}: lookbacks.window_samples must be in 4..100000")
    if not math.isclose(window_samples * card.sample_time_s, card.window_s, rel_tol=1e-3):
        raise ModelMismatchError(f"{path}: window_samples x sample_time_s differs from window_s")
    try:
        names = tuple(card.coverage["coordinates"])
        resolution = np.asarray(card.coverage["resolution"], dtype=float)
        threshold = float(card.coverage["threshold"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelMismatchError(
            f"{path}: malformed coverage ({type(exc).__name__}: {exc})"
        ) from exc
    if names != OPERATING_POINT:
        raise ModelMismatchError(f"{path}: coverage coordinates {list(names)}, expected "
                                 f"{list(OPERATING_POINT)}")  # fmt: skip
    if resolution.shape != (len(OPERATING_POINT),) or not np.all(resolution > 0):
        raise ModelMismatchError(f"{path}: coverage resolution must be {len(OPERATING_POINT)} > 0")
    if not (np.all(np.isfinite(resolution)) and 0 < threshold < math.inf):
        raise ModelMismatchError(f"{path}: coverage threshold must be finite and > 0")
    try:
        min_command_abs(card)
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelMismatchError(
            f"{path}: malformed coverage.evidence_floor ({type(exc).__name__}: {exc})"
        ) from exc
    return card


def min_command_abs(card: ClassifierCard) -> float:
    """Mean |command| (0..1) below which a window gives no evidence: the card's
    ``coverage.evidence_floor.min_command_abs``; ``inf`` when it is None (no band of the
    held-out units was told apart reliably), 0 for a card without it.

    Raises
    ------
    ValueError
        If the value is not None and not a number within 0..1.
    """
    floor = card.coverage.get("evidence_floor")
    if floor is None:
        return 0.0
    value = floor["min_command_abs"]
    if value is None:
        return math.inf
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
        raise ValueError(f"min_command_abs must be a number in 0..1 or null, got {value!r}")
    return float(value)


class ClassifierModel:
    """An exported window classifier, loaded without training code.

    Attributes
    ----------
    card : ClassifierCard
    model_id : str
    class_names : tuple of str
    window_s : float
        Window length, s.
    sample_time_s : float
        Sample time of window samples (the nominal model's), s.
    window_samples : int
        Samples per window.
    nominal_model_id : str
        The nominal model its residual features were made with.
    probability_threshold : float
        Default top-probability threshold under which a window is unknown.
    distance_threshold : float
        Distance to the nearest class beyond which a window is unknown.
    coverage : Coverage
        The operating region of the training windows.
    min_command_abs : float
        Mean |command| below which a window gives no evidence (``min_command_abs``).
    """

    def __init__(
        self,
        card: ClassifierCard,
        layers: tuple[tuple[np.ndarray, np.ndarray], ...],
        coverage: Coverage,
    ) -> None:
        self.card = card
        self.model_id = card.model_id
        self.class_names = card.class_names
        self.window_s = card.window_s
        self.sample_time_s = card.sample_time_s
        self.window_samples = card.lookbacks["window_samples"]
        self.nominal_model_id = card.nominal_model_id
        self.probability_threshold = float(card.unknown["probability_threshold"])
        self.distance_threshold = float(card.unknown["distance_threshold"])
        self._layers = layers
        self.coverage = coverage
        self.min_command_abs = min_command_abs(card)
        self._fill = np.array([card.feature_fill[f] for f in FEATURE_NAMES])
        self._center = np.array([card.scaling[f]["center"] for f in FEATURE_NAMES])
        self._scale = np.array([card.scaling[f]["scale"] for f in FEATURE_NAMES])
        self._distance_args = (
            self._center,
            self._scale,
            np.asarray(card.unknown["class_mean"], dtype=float),
            np.asarray(card.unknown["class_std"], dtype=float),
        )

    @classmethod
    def load(cls, model_dir: str | Path) -> ClassifierModel:
        """Load an exported folder (``model_card.json`` + the files it lists), without torch.

        Raises
        ------
        ModelMismatchError
            Naming the file and what is wrong or differs: missing folder or files, a file whose
            digest differs from the card's, a corrupt card or weights file, wrong kind, class
            names or features not this code's, weights whose scaling or sizes differ from the
            card.
        """
        model_dir = Path(model_dir)
        if not model_dir.is_dir():
            raise ModelMismatchError(f"{model_dir}: model directory missing")
        card = read_classifier_card(model_dir)
        arrays = load_weights(model_dir, card)
        path = model_dir / WEIGHTS_FILE
        center, scale = card.scaling_of(FEATURE_NAMES)
        if "center" not in arrays or "scale" not in arrays:
            raise ModelMismatchError(f"{path}: lacks the feature scaling arrays")
        got_c, got_s = arrays["center"], arrays["scale"]
        if got_c.shape != center.shape or not (
            np.allclose(got_c, center, rtol=1e-5, atol=1e-6)
            and np.allclose(got_s, scale, rtol=1e-5, atol=1e-6)
        ):
            raise ModelMismatchError(f"{path}: feature scaling differs from {CARD_FILE}")
        layers = mlp_layers(arrays, path)
        points = arrays.get(COVERAGE_ARRAY)
        if points is None or points.ndim != 2 or points.shape[1] != len(OPERATING_POINT):
            raise ModelMismatchError(f"{path}: lacks {COVERAGE_ARRAY} (N, {len(OPERATING_POINT)})")
        if len(points) < 1:
            raise ModelMismatchError(f"{path}: {COVERAGE_ARRAY} is empty")
        resolution = np.asarray(card.coverage["resolution"], dtype=float)
        coverage = Coverage(
            points=points / resolution,
            resolution=resolution,
            threshold=float(card.coverage["threshold"]),
        )
        model = cls(card, layers, coverage)
        # Compile (or load from numba's cache) every kernel of a decision now, not in the middle
        # of the first window of a running node.
        window = np.tile([0.5, 15.0, 2000.0, 3.0, 0.0, 0.0], (model.window_samples, 1))
        model.predict_proba(window_features(window, model.sample_time_s)[None])
        model.coverage.distance(np.zeros(len(OPERATING_POINT)))
        return model

    def fill(self, features: np.ndarray) -> np.ndarray:
        """Replace NaN features (B, F) by the training medians."""
        x = np.array(features, dtype=float, ndmin=2)
        return np.where(np.isnan(x), self._fill, x)

    def predict_proba(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Calibrated probabilities (B, C), each in [P_MIN, 1 - P_MIN], and the standardised RMS
        distance (B,) to the nearest class of raw features (B, F) (NaN filled here)."""
        x = self.fill(features)
        logits = mlp_forward(self._layers, x, self._center, self._scale)
        return bounded(softmax(logits / self.card.temperature)), _class_distance(
            x, *self._distance_args
        )


def bounded(p: np.ndarray) -> np.ndarray:
    """Probabilities (B, C) moved into [P_MIN, 1 - P_MIN], still summing to 1:
    ``P_MIN + (1 - C P_MIN) p``."""
    return P_MIN + (1.0 - p.shape[1] * P_MIN) * p


def mlp_layers(
    arrays: dict[str, np.ndarray], path: Path
) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """The (weight (out, in), bias (out,)) pairs of ``FeatureMLP.net`` as float64, in order.

    The decision evaluates these weights in a compiled kernel (``mlp_forward``, checked against
    the program at export): about 0.02 ms instead of the 0.5 ms of a call into the program
    (``bench/bench_classifier.py``).

    Raises
    ------
    ModelMismatchError
        Naming ``path`` when a layer is missing or its shape does not chain.
    """
    indices = sorted(
        int(k.split(".")[1]) for k in arrays if k.startswith("net.") and k.endswith(".weight")
    )
    layers = []
    n_in = len(FEATURE_NAMES)
    for i in indices:
        if f"net.{i}.bias" not in arrays:
            raise ModelMismatchError(f"{path}: layer net.{i} has no bias")
        w, b = arrays[f"net.{i}.weight"], arrays[f"net.{i}.bias"]
        if w.ndim != 2 or w.shape[1] != n_in or b.shape != (w.shape[0],):
            raise ModelMismatchError(
                f"{path}: layer net.{i} has shape {w.shape}, input {n_in} expected"
            )
        layers.append((w, b))
        n_in = w.shape[0]
    if not layers or n_in != len(CLASS_NAMES):
        raise ModelMismatchError(f"{path}: no MLP ending in {len(CLASS_NAMES)} class logits")
    return tuple(layers)


# The online decision path below is compiled (numba): with features of 20 numbers the numpy
# form spends its time dispatching calls, and a decision sits on the diagnosis' latency path.


@njit(cache=True)
def mlp_forward(
    layers: tuple[tuple[np.ndarray, np.ndarray], ...],
    x: np.ndarray,
    center: np.ndarray,
    scale: np.ndarray,
) -> np.ndarray:
    """``FeatureMLP.forward``, compiled: logits (B, C) of filled raw features ``x`` (B, F)."""
    out = np.empty((x.shape[0], layers[-1][1].shape[0]))
    for r in range(x.shape[0]):
        h = np.minimum(np.maximum((x[r] - center) / scale, -Z_CLIP), Z_CLIP)
        for k in range(len(layers)):
            w, b = layers[k]
            z = b.copy()
            for o in range(w.shape[0]):
                for i in range(w.shape[1]):
                    z[o] += w[o, i] * h[i]
            h = np.maximum(z, 0.0) if k < len(layers) - 1 else z
        out[r] = h
    return out


@njit(cache=True)
def _class_distance(
    x: np.ndarray,
    center: np.ndarray,
    scale: np.ndarray,
    class_mean: np.ndarray,
    class_std: np.ndarray,
) -> np.ndarray:
    """Standardised RMS distance (B,) of filled raw features (B, F) to the nearest class
    (class mean and std (C, F) in standardised units)."""
    out = np.full(x.shape[0], np.inf)
    for r in range(x.shape[0]):
        for c in range(class_mean.shape[0]):
            total = 0.0
            for f in range(x.shape[1]):
                d = ((x[r, f] - center[f]) / scale[f] - class_mean[c, f]) / class_std[c, f]
                total += d * d
            out[r] = min(out[r], np.sqrt(total / x.shape[1]))
    return out


@njit(cache=True)
def softmax(z: np.ndarray) -> np.ndarray:
    """Row-wise softmax of logits (B, C)."""
    out = np.empty(z.shape)
    for r in range(z.shape[0]):
        top = z[r].max()
        total = 0.0
        for c in range(z.shape[1]):
            out[r, c] = np.exp(z[r, c] - top)
            total += out[r, c]
        out[r] /= total
    return out
