"""Fault diagnosis from residual windows: features, MLP classifier, calibration, UNKNOWN, export,
online stream and offline diagnosis of a trace.

Pipeline (the same online in the classifier node and offline in ``diagnose_trace``)::

    telemetry --ResidualStream(nominal model)--> residual samples at the model's sample time
      --WindowFeaturizer--> one feature vector (core.features) per hop over the last window_s
      --ClassifierModel--> calibrated class probabilities + distance to the nearest class
      --DiagnosisStream--> raw label (class, or "unknown") -> hysteresis -> Decision

The classifier is an MLP on standardised window features (``FeatureMLP``), exported as a
``torch.export`` program (``model.pt2``) with ``model_card.json``. Probabilities are calibrated by
temperature scaling on held-out windows. A window is answered ``"unknown"`` when its calibrated
top probability is under ``unknown_threshold`` or its features are far from every class: the
distance is the RMS over features of ``(z - mean_c) / std_c`` (z the standardised features,
mean/std per class from the training windows), its threshold set on held-out windows.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections import deque
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numba import njit
from scipy.optimize import minimize_scalar
from torch import nn
from tqdm import tqdm

from thruster_fdd.core.data import CLASS_NAMES, Trace
from thruster_fdd.core.features import FEATURE_NAMES, WINDOW_SIGNALS, window_features
from thruster_fdd.core.nominal import NominalModel, code_version, load_card_json
from thruster_fdd.core.residuals import ResidualStream

KIND = "classifier"
"""``model_card.json`` kind of an exported classifier."""

UNKNOWN = "unknown"
"""Label of a window unlike every class (or not confident enough)."""

CARD_FILE = "model_card.json"
PROGRAM_FILE = "model.pt2"
FORMAT_VERSION = 1

DEFAULT_WINDOW_S = 20.0
"""Window length, s: 20 s beat 10 s on unseen units (docs/diagnosis.md)."""

MAX_GAP_PERIODS = 3.0
"""A step longer than this many sample times between valid samples restarts the window."""

Z_CLIP = 10.0
"""Standardised features are clipped to +-Z_CLIP inside the network (wild inputs stay finite)."""

STD_FLOOR = 0.05
"""Floor of a class's per-feature std in standardised units (the distance's denominator)."""

EVIDENCE_TAU_S = 5.0
"""Time constant of the decision layer's evidence accumulation, s of *excited* operation: each
window's log-probabilities enter an exponentially weighted mean that forgets at this rate only
while the thruster turns (tuned on validation units 400-405, docs/diagnosis.md)."""

EXCITATION_RANGE: tuple[float, float] = (0.3, 0.6)
"""Share of turning samples (feature ``active_fraction``) over which a window's evidence weight
ramps from 0 to 1: a window that mostly idles gives no evidence, so the label does not flip on
it (idle and station keeping confuse nominal and one broken blade)."""


# ---------------------------------------------------------------------------------------------
# Network


class FeatureMLP(nn.Module):
    """MLP from raw window features (B, F) to class logits (B, C); scaling held as buffers.

    Parameters
    ----------
    center, scale : np.ndarray, shape (F,)
        Standardisation ``z = clip((x - center) / scale, -Z_CLIP, Z_CLIP)``.
    hidden : tuple of int
        Hidden layer sizes (ReLU).
    n_classes : int
        Number of classes C.
    """

    def __init__(
        self, center: np.ndarray, scale: np.ndarray, hidden: tuple[int, ...], n_classes: int
    ) -> None:
        super().__init__()
        self.register_buffer("center", torch.tensor(center, dtype=torch.float32))
        self.register_buffer("scale", torch.tensor(scale, dtype=torch.float32))
        layers: list[nn.Module] = []
        n_in = len(center)
        for h in hidden:
            layers += [nn.Linear(n_in, h), nn.ReLU()]
            n_in = h
        layers.append(nn.Linear(n_in, n_classes))
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (B, C) of raw features ``x`` (B, F) (NaN already filled)."""
        z = torch.clamp((x - self.center) / self.scale, -Z_CLIP, Z_CLIP)
        return self.net(z)


# ---------------------------------------------------------------------------------------------
# Model card and loading


@dataclass(frozen=True)
class ClassifierCard:
    """``model_card.json`` of an exported classifier (DESIGN.md "Exported model").

    Attributes
    ----------
    kind : str
        ``"classifier"``.
    inputs : tuple of str
        Per-sample signals of a window (``WINDOW_SIGNALS``).
    features : tuple of str
        Network input, in order (``FEATURE_NAMES``).
    outputs : tuple of str
        Network output order: the class names.
    class_names : tuple of str
        DESIGN.md's six classes, in output order.
    scaling : dict
        ``{feature: {"center": float, "scale": float}}`` (median, IQR) in the feature's unit.
    feature_fill : dict
        ``{feature: float}``: training median that replaces an undefined (NaN) feature.
    sample_time_s : float
        Sample time of a window's samples (the nominal model's), s.
    window_s : float
        Window length, s.
    lookbacks : dict
        ``{"window_samples": int}``: samples per window.
    nominal_model_id : str
        ``model_id`` of the nominal model whose residuals the features were made with.
    temperature : float
        Softmax temperature from calibration (probabilities = softmax(logits / temperature)).
    unknown : dict
        ``{"probability_threshold", "distance_threshold", "class_mean", "class_std"}``: a window
        is unknown below the first or beyond the second; class mean/std are lists (C, F) in
        standardised units.
    architecture : str
        ``"mlp"``.
    hidden : tuple of int
        Hidden layer sizes.
    training_data_digest : str
        SHA-256 over the training traces' samples and labels.
    training_metrics : dict
        Accuracy, balanced accuracy, NLL and calibration of train / held-out windows.
    code_version, created, model_id : str
    format_version : int
    extra : dict
        Training options and data summary.
    """

    kind: str
    inputs: tuple[str, ...]
    features: tuple[str, ...]
    outputs: tuple[str, ...]
    class_names: tuple[str, ...]
    scaling: dict[str, dict[str, float]]
    feature_fill: dict[str, float]
    sample_time_s: float
    window_s: float
    lookbacks: dict[str, int]
    nominal_model_id: str
    temperature: float
    unknown: dict[str, Any]
    architecture: str
    hidden: tuple[int, ...]
    training_data_digest: str
    training_metrics: dict[str, Any]
    code_version: str
    created: str
    model_id: str
    format_version: int = FORMAT_VERSION
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        """The card as pretty JSON text."""
        return json.dumps(asdict(self), indent=2) + "\n"


_CARD_TYPES: dict[str, type | tuple[type, ...]] = {
    "kind": str,
    "inputs": list,
    "features": list,
    "outputs": list,
    "class_names": list,
    "scaling": dict,
    "feature_fill": dict,
    "sample_time_s": (int, float),
    "window_s": (int, float),
    "lookbacks": dict,
    "nominal_model_id": str,
    "temperature": (int, float),
    "unknown": dict,
    "architecture": str,
    "hidden": list,
    "training_data_digest": str,
    "training_metrics": dict,
    "code_version": str,
    "created": str,
    "model_id": str,
    "format_version": int,
}


def read_classifier_card(model_dir: str | Path) -> ClassifierCard:
    """Read and check ``model_dir/model_card.json`` against what this code expects.

    Raises
    ------
    ValueError
        Naming the file and what is wrong or differs: missing, not JSON, a missing or mistyped
        field, another kind, class names or features other than DESIGN.md's / this code's,
        inconsistent sizes.
    """
    path, raw = load_card_json(model_dir, _CARD_TYPES, KIND)
    expected: dict[str, tuple[str, ...]] = {
        "class_names": CLASS_NAMES,
        "outputs": CLASS_NAMES,
        "features": FEATURE_NAMES,
        "inputs": WINDOW_SIGNALS,
    }
    for key, want in expected.items():
        if tuple(raw[key]) != want:
            raise ValueError(f"{path}: {key} are {raw[key]}, expected {list(want)}")
    if raw["format_version"] != FORMAT_VERSION:
        raise ValueError(
            f"{path}: format_version is {raw['format_version']}, expected {FORMAT_VERSION}"
        )
    try:
        card = ClassifierCard(
            kind=raw["kind"],
            inputs=tuple(raw["inputs"]),
            features=tuple(raw["features"]),
            outputs=tuple(raw["outputs"]),
            class_names=tuple(raw["class_names"]),
            scaling={f: {k: float(v) for k, v in raw["scaling"][f].items()} for f in FEATURE_NAMES},
            feature_fill={f: float(raw["feature_fill"][f]) for f in FEATURE_NAMES},
            sample_time_s=float(raw["sample_time_s"]),
            window_s=float(raw["window_s"]),
            lookbacks={"window_samples": int(raw["lookbacks"]["window_samples"])},
            nominal_model_id=raw["nominal_model_id"],
            temperature=float(raw["temperature"]),
            unknown=dict(raw["unknown"]),
            architecture=raw["architecture"],
            hidden=tuple(int(h) for h in raw["hidden"]),
            training_data_digest=raw["training_data_digest"],
            training_metrics=raw["training_metrics"],
            code_version=raw["code_version"],
            created=raw["created"],
            model_id=raw["model_id"],
            format_version=raw["format_version"],
            extra=dict(raw.get("extra", {})),
        )
        mean = np.asarray(card.unknown["class_mean"], dtype=float)
        std = np.asarray(card.unknown["class_std"], dtype=float)
        p_thr = float(card.unknown["probability_threshold"])
        d_thr = float(card.unknown["distance_threshold"])
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: malformed field ({type(exc).__name__}: {exc})") from exc
    shape = (len(CLASS_NAMES), len(FEATURE_NAMES))
    if mean.shape != shape or std.shape != shape or not np.all(std > 0):
        raise ValueError(f"{path}: unknown.class_mean/class_std must be {shape}, std > 0")
    if not (0.0 <= p_thr <= 1.0 and d_thr > 0):
        raise ValueError(f"{path}: unknown thresholds out of range ({p_thr}, {d_thr})")
    if not (card.sample_time_s > 0 and card.window_s > 0 and card.temperature > 0):
        raise ValueError(f"{path}: sample_time_s, window_s and temperature must be > 0")
    if card.lookbacks["window_samples"] < 4:
        raise ValueError(f"{path}: lookbacks.window_samples must be >= 4")
    if not all(card.scaling[f]["scale"] > 0 for f in FEATURE_NAMES):
        raise ValueError(f"{path}: every feature scale must be > 0")
    return card


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
    """

    def __init__(
        self, card: ClassifierCard, layers: tuple[tuple[np.ndarray, np.ndarray], ...]
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
        """Load ``model_dir`` (``model_card.json`` + ``model.pt2``).

        Raises
        ------
        ValueError
            Naming the file and what is wrong or differs: missing directory or files, corrupt
            card or program, wrong kind, class names not DESIGN.md's, features not this code's,
            a program whose scaling or output size differs from the card.
        """
        model_dir = Path(model_dir)
        if not model_dir.is_dir():
            raise ValueError(f"{model_dir}: model directory missing")
        card = read_classifier_card(model_dir)
        prog_path = model_dir / PROGRAM_FILE
        if not prog_path.is_file():
            raise ValueError(f"{prog_path}: exported program missing")
        try:
            program = torch.export.load(prog_path)
        except Exception as exc:
            raise ValueError(f"{prog_path}: not a loadable torch export program ({exc})") from exc
        state = program.state_dict
        center = np.array([card.scaling[f]["center"] for f in FEATURE_NAMES])
        scale = np.array([card.scaling[f]["scale"] for f in FEATURE_NAMES])
        if "center" not in state or "scale" not in state:
            raise ValueError(f"{prog_path}: program lacks the feature scaling buffers")
        got_c, got_s = state["center"].double().numpy(), state["scale"].double().numpy()
        if got_c.shape != center.shape or not (
            np.allclose(got_c, center, rtol=1e-5, atol=1e-6)
            and np.allclose(got_s, scale, rtol=1e-5, atol=1e-6)
        ):
            raise ValueError(f"{prog_path}: feature scaling differs from {CARD_FILE}")
        module = program.module()
        try:
            with torch.inference_mode():
                out = module(torch.zeros(2, len(FEATURE_NAMES)))
        except Exception as exc:
            raise ValueError(
                f"{prog_path}: the program fails on (B, {len(FEATURE_NAMES)}) features ({exc})"
            ) from exc
        if tuple(out.shape) != (2, len(CLASS_NAMES)):
            raise ValueError(
                f"{prog_path}: program outputs shape {tuple(out.shape)[1:]}, expected "
                f"({len(CLASS_NAMES)},) class logits"
            )
        layers = _mlp_layers(state, prog_path)
        _check_compiled_path(module, layers, center, scale, prog_path)
        model = cls(card, layers)
        # Compile (or load from numba's cache) every kernel of a decision now, not in the middle
        # of the first window of a running node.
        window = np.tile([0.5, 15.0, 2000.0, 3.0, 0.0, 0.0], (model.window_samples, 1))
        model.predict_proba(window_features(window, model.sample_time_s)[None])
        return model

    def fill(self, features: np.ndarray) -> np.ndarray:
        """Replace NaN features (B, F) by the training medians."""
        x = np.array(features, dtype=float, ndmin=2)
        return np.where(np.isnan(x), self._fill, x)

    def predict_proba(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Calibrated probabilities (B, C) and the standardised RMS distance (B,) to the nearest
        class of raw features (B, F) (NaN filled here)."""
        x = self.fill(features)
        logits = _mlp_forward(self._layers, x, self._center, self._scale)
        return _softmax(logits / self.card.temperature), _class_distance(x, *self._distance_args)


def _mlp_layers(state: dict[str, Any], path: Path) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """The (weight (out, in), bias (out,)) pairs of ``FeatureMLP.net`` as float64, in order.

    The decision evaluates these weights in a compiled kernel (``_mlp_forward``, checked
    against the program at load): about 0.02 ms instead of the 0.5 ms of a call into the
    program (``bench/bench_classifier.py``).
    """
    indices = sorted(
        int(k.split(".")[1]) for k in state if k.startswith("net.") and k.endswith(".weight")
    )
    layers = []
    n_in = len(FEATURE_NAMES)
    for i in indices:
        if f"net.{i}.bias" not in state:
            raise ValueError(f"{path}: layer net.{i} has no bias")
        w = state[f"net.{i}.weight"].detach().double().numpy().copy()
        b = state[f"net.{i}.bias"].detach().double().numpy().copy()
        if w.ndim != 2 or w.shape[1] != n_in or b.shape != (w.shape[0],):
            raise ValueError(f"{path}: layer net.{i} has shape {w.shape}, input {n_in} expected")
        layers.append((w, b))
        n_in = w.shape[0]
    if not layers or n_in != len(CLASS_NAMES):
        raise ValueError(f"{path}: no MLP ending in {len(CLASS_NAMES)} class logits")
    return tuple(layers)


# The online decision path below is compiled (numba): with features of 20 numbers the numpy
# form spends its time dispatching calls, and a decision sits on the diagnosis' latency path.


@njit(cache=True)
def _mlp_forward(
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


def _check_compiled_path(
    module: Any,
    layers: tuple[tuple[np.ndarray, np.ndarray], ...],
    center: np.ndarray,
    scale: np.ndarray,
    path: Path,
) -> None:
    """ValueError if ``_mlp_forward`` does not reproduce the program on probe features."""
    rng = np.random.default_rng(0)
    x = center + scale * rng.normal(scale=3.0, size=(16, len(center)))
    with torch.inference_mode():
        ref = module(torch.tensor(x, dtype=torch.float32)).double().numpy()
    fast = _mlp_forward(layers, x, center, scale)
    err = float(np.max(np.abs(fast - ref)))
    if not err <= 1e-3 * max(1.0, float(np.max(np.abs(ref)))):
        raise ValueError(
            f"{path}: the program's graph differs from a ReLU MLP with these weights "
            f"(max logit difference {err:.3g})"
        )


@njit(cache=True)
def _softmax(z: np.ndarray) -> np.ndarray:
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


class WindowFeaturizer:
    """Collects valid residual samples into a sliding window; features every hop.

    Parameters
    ----------
    window_samples : int
        Samples per window (>= 4).
    hop_samples : int
        Samples between two feature vectors once the window is full (>= 1).
    sample_time_s : float
        Expected time between samples, s; a step longer than ``MAX_GAP_PERIODS`` of it, or
        time going back, restarts the window.
    """

    def __init__(self, window_samples: int, hop_samples: int, sample_time_s: float) -> None:
        if window_samples < 4 or hop_samples < 1 or not sample_time_s > 0:
            raise ValueError(
                f"need window_samples >= 4, hop_samples >= 1, sample_time_s > 0; got "
                f"{window_samples}, {hop_samples}, {sample_time_s}"
            )
        self.window_samples = window_samples
        self.hop_samples = hop_samples
        self.sample_time_s = sample_time_s
        # Rows (t, *values) in a ring twice the window long: the window is always the contiguous
        # slice ending at ``_end``; when the ring is full its last rows move to the front.
        self._ring = np.empty((2 * window_samples, 1 + len(WINDOW_SIGNALS)))
        self._end = 0
        self._count = 0
        self._since = 0
        self._fresh = True
        self._last_t: float | None = None

    def reset(self) -> None:
        """Empty the window."""
        self._end = 0
        self._count = 0
        self._since = 0
        self._fresh = True
        self._last_t = None

    def push(
        self, t_s: float, values: tuple[float, float, float, float, float, float], valid: bool
    ) -> tuple[float, float, np.ndarray] | None:
        """Add one sample; every hop with a full window return ``(t_start, t_end, features)``.

        Parameters
        ----------
        t_s : float
            Sample time, s.
        values : tuple of 6 float
            ``WINDOW_SIGNALS``: command, voltage (V), rpm, current (A), residual rpm, residual
            current (A).
        valid : bool
            False (or a non-finite value) skips the sample.

        Returns
        -------
        (t_start, t_end, features) or None
            Times of the window's first and last sample (s) and ``window_features`` (F,).
        """
        if not valid or not (math.isfinite(t_s) and all(math.isfinite(v) for v in values)):
            return None
        if self._last_t is not None:
            dt = t_s - self._last_t
            if dt <= 0 or dt > MAX_GAP_PERIODS * self.sample_time_s:
                self.reset()
        self._last_t = t_s
        if self._end == len(self._ring):
            keep = self.window_samples - 1
            self._ring[:keep] = self._ring[self._end - keep : self._end]
            self._end = keep
        self._ring[self._end, 0] = t_s
        self._ring[self._end, 1:] = values
        self._end += 1
        self._count = min(self._count + 1, self.window_samples)
        self._since += 1
        if self._count < self.window_samples:
            return None
        if not (self._fresh or self._since >= self.hop_samples):
            return None
        self._fresh = False
        self._since = 0
        arr = self._ring[self._end - self._count : self._end]
        return float(arr[0, 0]), float(arr[-1, 0]), window_features(arr[:, 1:], self.sample_time_s)


@dataclass(frozen=True)
class Decision:
    """One diagnosis of one thruster over the last window.

    Attributes
    ----------
    t_s : float
        Time of the window's last sample, s.
    label : str
        Condition after hysteresis: a class name or ``"unknown"``.
    raw_label : str
        This window's own answer: the most probable class, or ``"unknown"`` when the top
        probability is under the threshold or the features are unlike every class.
    probabilities : dict of str to float
        Calibrated class probabilities (sum 1).
    confidence : float
        Probability of the most probable class.
    window_s : float
        Window length, s.
    t_start_s : float
        Time of the window's first sample, s.
    distance : float
        Distance of the window's features to the nearest class (standardised RMS).
    """

    t_s: float
    label: str
    raw_label: str
    probabilities: dict[str, float]
    confidence: float
    window_s: float
    t_start_s: float
    distance: float


class DiagnosisStream:
    """Online diagnosis of one thruster: residual samples in, a Decision every hop.

    Parameters
    ----------
    model : ClassifierModel
        The exported classifier.
    hop_s : float
        Time between decisions once a window is full, s (rounded to whole samples).
    hysteresis : int
        The reported label changes only when this many consecutive evidence labels agree on a
        new one (``"unknown"`` included); it starts as ``"unknown"``.
    unknown_threshold : float or None
        Top probability under which a window is unknown; None uses the card's.
    evidence_tau_s : float
        Time constant of the evidence accumulation, s of excited operation
        (``EVIDENCE_TAU_S``); 0 turns accumulation off (the label follows the raw labels).
    excitation_range : (float, float)
        ``active_fraction`` below which a window weighs 0 and above which it weighs 1
        (``EXCITATION_RANGE``).

    Decision layer: each window's calibrated log-probabilities ``log p`` and its "unlike every
    class" flag enter exponentially weighted means with weight ``w`` (0..1, from the window's
    share of turning samples); the forgetting factor is ``exp(-w hop / evidence_tau_s)``, so a
    window without excitation neither adds evidence nor forgets it. The evidence label is the
    argmax of ``softmax(mean log p)`` (a weighted geometric mean of recent windows), or
    ``"unknown"`` when the weighted share of unlike windows exceeds 0.5 or its top probability
    is under ``unknown_threshold``; before any excited window it is the raw label. Hysteresis
    then acts on the evidence labels. ``raw_label``, ``probabilities`` and ``confidence`` of a
    Decision stay the window's own.
    """

    def __init__(
        self,
        model: ClassifierModel,
        *,
        hop_s: float = 1.0,
        hysteresis: int = 2,
        unknown_threshold: float | None = None,
        evidence_tau_s: float = EVIDENCE_TAU_S,
        excitation_range: tuple[float, float] = EXCITATION_RANGE,
    ) -> None:
        if not (math.isfinite(hop_s) and hop_s > 0):
            raise ValueError(f"hop_s must be > 0, got {hop_s}")
        if not (math.isfinite(evidence_tau_s) and evidence_tau_s >= 0):
            raise ValueError(f"evidence_tau_s must be >= 0, got {evidence_tau_s}")
        lo, hi = (float(v) for v in excitation_range)
        if not (0.0 <= lo < hi <= 1.0):
            raise ValueError(f"excitation_range must satisfy 0 <= lo < hi <= 1, got {lo}, {hi}")
        if hysteresis < 1:
            raise ValueError(f"hysteresis must be >= 1, got {hysteresis}")
        if unknown_threshold is not None and not 0.0 <= unknown_threshold <= 1.0:
            raise ValueError(f"unknown_threshold must be in [0, 1], got {unknown_threshold}")
        self.model = model
        self.hop_s = hop_s
        self.hysteresis = hysteresis
        self.unknown_threshold = (
            model.probability_threshold if unknown_threshold is None else unknown_threshold
        )
        self.evidence_tau_s = float(evidence_tau_s)
        self.excitation_range = (lo, hi)
        hop_samples = max(1, round(hop_s / model.sample_time_s))
        self._hop_time_s = hop_samples * model.sample_time_s
        self._windows = WindowFeaturizer(model.window_samples, hop_samples, model.sample_time_s)
        self._recent: deque[str] = deque(maxlen=hysteresis)
        self._label = UNKNOWN
        self._active_index = FEATURE_NAMES.index("active_fraction")
        self._log_p = np.zeros(len(model.class_names))
        self._weight = 0.0
        self._unlike = 0.0

    def reset(self) -> None:
        """Forget the window, the evidence and the label history (the label returns to
        ``"unknown"``)."""
        self._windows.reset()
        self._recent.clear()
        self._label = UNKNOWN
        self._log_p = np.zeros(len(self.model.class_names))
        self._weight = 0.0
        self._unlike = 0.0

    def push(
        self,
        t_s: float,
        command: float,
        voltage: float,
        rpm: float,
        current: float,
        residual_rpm: float,
        residual_current: float,
        valid: bool,
    ) -> Decision | None:
        """Feed one residual sample (``core.residuals.ResidualSample`` + its command, voltage).

        Parameters
        ----------
        t_s : float
            Sample time, s.
        command, voltage, rpm, current : float
            The telemetry sample: -1..1, V, rpm, A.
        residual_rpm, residual_current : float
            Measured minus predicted rpm and current (A).
        valid : bool
            ``ResidualSample.valid``; invalid samples are skipped.

        Returns
        -------
        Decision or None
            A decision every ``hop_s`` once a window is full, else None. A time gap restarts
            the window (the label is kept).
        """
        out = self._windows.push(
            t_s, (command, voltage, rpm, current, residual_rpm, residual_current), valid
        )
        if out is None:
            return None
        t_start, t_end, features = out
        return self._decide(t_start, t_end, features)

    def _decide(self, t_start: float, t_end: float, features: np.ndarray) -> Decision:
        probs, dist = self.model.predict_proba(features[None])
        p = probs[0]
        best = int(np.argmax(p))
        confidence = float(p[best])
        distance = float(dist[0])
        unlike = distance > self.model.distance_threshold
        raw = (
            UNKNOWN
            if unlike or confidence < self.unknown_threshold
            else self.model.class_names[best]
        )
        evidence = self._evidence_label(features, p, unlike, raw)
        self._recent.append(evidence)
        if len(self._recent) == self.hysteresis and len(set(self._recent)) == 1:
            self._label = evidence
        return Decision(
            t_s=t_end,
            label=self._label,
            raw_label=raw,
            probabilities={c: float(v) for c, v in zip(self.model.class_names, p, strict=True)},
            confidence=confidence,
            window_s=self.model.window_s,
            t_start_s=t_start,
            distance=distance,
        )

    def _evidence_label(self, features: np.ndarray, p: np.ndarray, unlike: bool, raw: str) -> str:
        """Add one window to the accumulated evidence; the label it supports (class docstring)."""
        if self.evidence_tau_s == 0:
            return raw
        lo, hi = self.excitation_range
        active = float(features[self._active_index])
        w = min(max((active - lo) / (hi - lo), 0.0), 1.0) if math.isfinite(active) else 0.0
        if w > 0:
            keep = math.exp(-w * self._hop_time_s / self.evidence_tau_s)
            self._log_p = keep * self._log_p + w * np.log(np.maximum(p, 1e-9))
            self._weight = keep * self._weight + w
            self._unlike = keep * self._unlike + w * float(unlike)
        if self._weight <= 0:
            return raw
        mean = self._log_p / self._weight
        q = np.exp(mean - mean.max())
        q /= q.sum()
        best = int(np.argmax(q))
        if self._unlike / self._weight > 0.5 or q[best] < self.unknown_threshold:
            return UNKNOWN
        return self.model.class_names[best]


# ---------------------------------------------------------------------------------------------
# Offline: a whole trace through the same code path


def check_pair(nominal: NominalModel, classifier: ClassifierModel, classifier_dir: Any) -> None:
    """ValueError if the classifier was not made with this nominal model's residuals."""
    if classifier.nominal_model_id != nominal.model_id:
        raise ValueError(
            f"{Path(classifier_dir) / CARD_FILE}: made with nominal model "
            f"{classifier.nominal_model_id!r}, but the nominal model is {nominal.model_id!r}"
        )
    if not math.isclose(classifier.sample_time_s, nominal.sample_time_s, rel_tol=1e-6):
        raise ValueError(
            f"{Path(classifier_dir) / CARD_FILE}: sample_time_s {classifier.sample_time_s} "
            f"differs from the nominal model's {nominal.sample_time_s}"
        )


def trace_decisions(
    trace: Trace,
    nominal: NominalModel,
    classifier: ClassifierModel,
    *,
    hop_s: float = 1.0,
    hysteresis: int = 2,
    unknown_threshold: float | None = None,
    evidence_tau_s: float = EVIDENCE_TAU_S,
) -> list[Decision]:
    """Run a trace sample by sample through ResidualStream and DiagnosisStream.

    Both start from a reset state, exactly as the nodes do on a fresh thruster stream.
    ``evidence_tau_s`` = 0 gives the decision layer without evidence accumulation.
    """
    residuals = ResidualStream(nominal)
    residuals.reset()
    stream = DiagnosisStream(
        classifier,
        hop_s=hop_s,
        hysteresis=hysteresis,
        unknown_threshold=unknown_threshold,
        evidence_tau_s=evidence_tau_s,
    )
    decisions = []
    columns = (trace.t, trace.command, trace.voltage, trace.rpm, trace.current)
    for t, c, v, r, i in zip(*(a.tolist() for a in columns), strict=True):
        s = residuals.push(t, c, v, r, i)
        if s is None:
            continue
        d = stream.push(t, c, v, r, i, s.residual_rpm, s.residual_current_a, s.valid)
        if d is not None:
            decisions.append(d)
    return decisions


def summarize_decisions(decisions: list[Decision], class_names: tuple[str, ...]) -> dict:
    """DESIGN.md diagnose JSON from decisions.

    ``overall.label`` is the class of highest mean probability over the windows (``"unknown"``
    when most windows' raw label is unknown, or there is no window); ``overall.confidence`` is
    that mean probability.
    """
    windows = [
        {
            "t_start": d.t_start_s,
            "t_end": d.t_s,
            "label": d.label,
            "raw_label": d.raw_label,
            "confidence": d.confidence,
            "probabilities": d.probabilities,
        }
        for d in decisions
    ]
    if not decisions:
        return {"overall": {"label": UNKNOWN, "confidence": 0.0}, "windows": windows}
    mean = np.mean([[d.probabilities[c] for c in class_names] for d in decisions], axis=0)
    best = int(np.argmax(mean))
    unknown_share = np.mean([d.raw_label == UNKNOWN for d in decisions])
    label = UNKNOWN if unknown_share > 0.5 else class_names[best]
    return {"overall": {"label": label, "confidence": float(mean[best])}, "windows": windows}


def diagnose_trace(
    trace: Trace, nominal_dir: str | Path, classifier_dir: str | Path, *, hop_s: float = 1.0
) -> dict:
    """Offline diagnosis of a trace with exported models (the nodes' code path).

    Parameters
    ----------
    trace : Trace
        Telemetry at any rate (the residual stream decimates to the model's sample time).
    nominal_dir, classifier_dir : str or Path
        Exported nominal model and classifier; the classifier must have been made with that
        nominal model.
    hop_s : float
        Time between window decisions, s.

    Returns
    -------
    dict
        ``{"overall": {"label", "confidence"}, "windows": [{"t_start", "t_end", "label",
        "raw_label", "confidence", "probabilities": {class: p}}]}`` (DESIGN.md keys, times in s).

    Raises
    ------
    ValueError
        If a model does not load or the two do not belong together.
    """
    nominal = NominalModel.load(nominal_dir)
    classifier = ClassifierModel.load(classifier_dir)
    check_pair(nominal, classifier, classifier_dir)
    decisions = trace_decisions(trace, nominal, classifier, hop_s=hop_s)
    return summarize_decisions(decisions, classifier.class_names)


# ---------------------------------------------------------------------------------------------
# Training


@dataclass(frozen=True)
class ClassifierConfig:
    """Training options of the window classifier.

    Attributes
    ----------
    window_s : float
        Window length, s.
    hop_s : float
        Hop between training windows, s.
    hidden : tuple of int
        Hidden layer sizes.
    epochs : int
        Full-batch Adam epochs.
    lr : float
        Learning rate.
    weight_decay : float
        L2 penalty.
    probability_threshold : float
        Default top-probability threshold of UNKNOWN.
    distance_quantile : float
        Held-out quantile of the nearest-class distance that, times ``distance_margin``, sets
        the distance threshold of UNKNOWN.
    distance_margin : float
        Factor on that quantile.
    holdout_every : int
        With >= 3 traces of a class, every this-many-th trace of it (by order; the last one when
        there are fewer) is held out for calibration; otherwise the last ``holdout_fraction`` of
        every trace is.
    holdout_fraction : float
        Time-split fraction (see above).
    """

    window_s: float = DEFAULT_WINDOW_S
    hop_s: float = 1.0
    hidden: tuple[int, ...] = (64, 64)
    epochs: int = 400
    lr: float = 3e-3
    weight_decay: float = 1e-4
    probability_threshold: float = 0.5
    distance_quantile: float = 0.995
    distance_margin: float = 1.5
    holdout_every: int = 4
    holdout_fraction: float = 0.25


@dataclass(frozen=True)
class WindowSet:
    """Window features of labelled traces.

    Attributes
    ----------
    x : np.ndarray, shape (m, F)
        Raw features (NaN where undefined).
    y : np.ndarray, shape (m,)
        Class index into ``CLASS_NAMES``.
    trace : np.ndarray, shape (m,)
        Index of the trace each window comes from.
    t_start, t_end : np.ndarray, shape (m,)
        Window times, s.
    """

    x: np.ndarray
    y: np.ndarray
    trace: np.ndarray
    t_start: np.ndarray
    t_end: np.ndarray

    def subset(self, mask: np.ndarray) -> WindowSet:
        """The windows where ``mask`` (m,) is True."""
        return WindowSet(
            self.x[mask], self.y[mask], self.trace[mask], self.t_start[mask], self.t_end[mask]
        )


def trace_windows(
    traces: list[Trace],
    nominal: NominalModel,
    *,
    window_s: float,
    hop_s: float,
    progress: bool = False,
) -> WindowSet:
    """Labelled window features of traces, through ResidualStream and WindowFeaturizer.

    A window is kept when all its samples carry the same label (a window across a fault onset
    is dropped). Labels come from ``Trace.sample_labels()``.

    Raises
    ------
    ValueError
        If a trace has no labels, or no trace yields a full window.
    """
    n = round(window_s / nominal.sample_time_s)
    hop = max(1, round(hop_s / nominal.sample_time_s))
    xs, ys, ids, t0s, t1s = [], [], [], [], []
    index = {c: i for i, c in enumerate(CLASS_NAMES)}
    for k, tr in enumerate(tqdm(traces, desc="window features", disable=not progress)):
        labels = tr.sample_labels()
        if labels is None:
            name = tr.thruster_id or f"#{k}"
            raise ValueError(f"trace {name} has no condition column or labels to train on")
        residuals = ResidualStream(nominal)
        residuals.reset()
        windows = WindowFeaturizer(n, hop, nominal.sample_time_s)
        columns = (tr.t, tr.command, tr.voltage, tr.rpm, tr.current)
        for t, c, v, r, i in zip(*(a.tolist() for a in columns), strict=True):
            s = residuals.push(t, c, v, r, i)
            if s is None:
                continue
            out = windows.push(t, (c, v, r, i, s.residual_rpm, s.residual_current_a), s.valid)
            if out is None:
                continue
            t0, t1, f = out
            lo, hi = np.searchsorted(tr.t, [t0, t1], side="left")
            window_labels = set(labels[lo : hi + 1].tolist())
            if len(window_labels) != 1:
                continue
            xs.append(f)
            ys.append(index[window_labels.pop()])
            ids.append(k)
            t0s.append(t0)
            t1s.append(t1)
    if not xs:
        raise ValueError(f"no trace is long enough for one {window_s:g} s window of valid samples")
    return WindowSet(
        np.asarray(xs), np.asarray(ys), np.asarray(ids), np.asarray(t0s), np.asarray(t1s)
    )


def holdout_mask(
    windows: WindowSet, traces: list[Trace], config: ClassifierConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Held-out (calibration) and dropped windows, each a bool mask (m,).

    Whole traces are held out when a class has >= 3 traces, else each trace's last
    ``holdout_fraction``; with the time split, windows across the split are dropped.
    """
    held = np.zeros(len(windows.y), dtype=bool)
    dropped = np.zeros(len(windows.y), dtype=bool)
    by_class: dict[int, list[int]] = {}
    for k in np.unique(windows.trace):
        by_class.setdefault(int(np.bincount(windows.y[windows.trace == k]).argmax()), []).append(k)
    for ks in by_class.values():
        if len(ks) >= 3:
            chosen = ks[config.holdout_every - 1 :: config.holdout_every] or ks[-1:]
            for k in chosen:
                held |= windows.trace == k
        else:
            for k in ks:
                tr = traces[k]
                split = tr.t[0] + (1.0 - config.holdout_fraction) * (tr.t[-1] - tr.t[0])
                mine = windows.trace == k
                held |= mine & (windows.t_start >= split)
                dropped |= mine & (windows.t_start < split) & (windows.t_end >= split)
    return held, dropped


def class_statistics(z: np.ndarray, y: np.ndarray, n_classes: int) -> tuple[np.ndarray, ...]:
    """Per-class mean and std (C, F) of standardised features ``z`` (m, F); std floored."""
    mean = np.zeros((n_classes, z.shape[1]))
    std = np.ones((n_classes, z.shape[1]))
    for c in range(n_classes):
        zc = z[y == c]
        if len(zc):
            mean[c] = zc.mean(axis=0)
            std[c] = np.maximum(zc.std(axis=0), STD_FLOOR)
    return mean, std


def fit_temperature(logits: np.ndarray, y: np.ndarray) -> float:
    """Temperature T minimising the NLL of softmax(logits / T) on held-out windows."""

    def nll(log_t: float) -> float:
        p = _softmax(logits / math.exp(log_t))
        return float(-np.mean(np.log(p[np.arange(len(y)), y] + 1e-12)))

    res = minimize_scalar(nll, bounds=(-3.0, 3.0), method="bounded")
    return float(math.exp(res.x))


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


def fit_mlp(
    x: np.ndarray, y: np.ndarray, center: np.ndarray, scale: np.ndarray, config: ClassifierConfig,
    seed: int, *, progress: bool = False,
) -> FeatureMLP:  # fmt: skip
    """Train a FeatureMLP on filled features (m, F) and labels (m,), class-balanced loss."""
    torch.manual_seed(seed)
    net = FeatureMLP(center, scale, config.hidden, len(CLASS_NAMES))
    xt = torch.tensor(x, dtype=torch.float32)
    yt = torch.tensor(y, dtype=torch.long)
    counts = np.bincount(y, minlength=len(CLASS_NAMES)).astype(float)
    weight = torch.tensor(
        np.where(counts > 0, counts.sum() / np.maximum(counts, 1) / len(CLASS_NAMES), 0.0),
        dtype=torch.float32,
    )
    opt = torch.optim.Adam(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    loss_fn = nn.CrossEntropyLoss(weight=weight)
    for _ in tqdm(range(config.epochs), desc="classifier mlp", disable=not progress):
        opt.zero_grad()
        loss = loss_fn(net(xt), yt)
        loss.backward()
        opt.step()
    return net.eval()


def training_digest(traces: list[Trace]) -> str:
    """SHA-256 (hex) over every trace's samples (t, command, voltage, rpm, current) and labels."""
    h = hashlib.sha256()
    for tr in traces:
        arr = np.stack([tr.t, tr.command, tr.voltage, tr.rpm, tr.current], axis=1)
        h.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
        labels = tr.sample_labels()
        h.update("\n".join([] if labels is None else labels.tolist()).encode())
    return h.hexdigest()


def train_classifier(
    traces: list[Trace],
    nominal_dir: str | Path,
    out_dir: str | Path | None,
    *,
    seed: int = 0,
    config: ClassifierConfig | None = None,
    progress: bool = False,
) -> ClassifierCard:
    """Train, calibrate and (with ``out_dir``) export the window classifier.

    Parameters
    ----------
    traces : list of Trace
        Labelled traces (``condition`` or per-sample ``labels``) of any rate.
    nominal_dir : str or Path
        Exported nominal model that makes the residuals.
    out_dir : str or Path or None
        Where to write ``model.pt2`` and ``model_card.json``; None trains without exporting
        (the card is still returned).
    seed : int
        Seed of initialisation.
    config : ClassifierConfig or None
        Options; None uses the defaults.
    progress : bool
        Show progress bars.

    Returns
    -------
    ClassifierCard

    Raises
    ------
    ValueError
        If traces are unlabelled or too short, a class has no training window, or there is no
        held-out window.
    """
    config = config or ClassifierConfig()
    if not traces:
        raise ValueError("no traces to train on")
    nominal = NominalModel.load(nominal_dir)
    windows = trace_windows(
        traces, nominal, window_s=config.window_s, hop_s=config.hop_s, progress=progress
    )
    held, dropped = holdout_mask(windows, traces, config)
    train, val = windows.subset(~dropped & ~held), windows.subset(~dropped & held)
    missing = [c for i, c in enumerate(CLASS_NAMES) if not np.any(train.y == i)]
    if missing:
        raise ValueError(f"no training window of class(es) {', '.join(missing)}")
    if len(val.y) == 0:
        raise ValueError("no held-out window for calibration; give longer or more traces")
    fill = np.nanmedian(train.x, axis=0)
    fill = np.where(np.isnan(fill), 0.0, fill)
    x_train = np.where(np.isnan(train.x), fill, train.x)
    x_val = np.where(np.isnan(val.x), fill, val.x)
    # Scaling from the defined values only: a feature that is often undefined (NaN, filled with
    # its median) must not get a collapsed IQR.
    q25, q75 = np.nanpercentile(train.x, [25.0, 75.0], axis=0)
    center = fill
    scale = np.where(np.isnan(q75 - q25), 1.0, q75 - q25)
    scale = np.maximum(scale, 1e-3 * np.maximum(np.abs(center), 1.0))
    net = fit_mlp(x_train, train.y, center, scale, config, seed, progress=progress)
    with torch.inference_mode():
        logit_train = net(torch.tensor(x_train, dtype=torch.float32)).double().numpy()
        logit_val = net(torch.tensor(x_val, dtype=torch.float32)).double().numpy()
    temperature = fit_temperature(logit_val, val.y)
    z_train = np.clip((x_train - center) / scale, -1e6, 1e6)
    class_mean, class_std = class_statistics(z_train, train.y, len(CLASS_NAMES))
    z_val = (x_val - center) / scale
    d_val = np.sqrt(
        np.mean(((z_val[:, None, :] - class_mean[None]) / class_std[None]) ** 2, axis=2)
    ).min(axis=1)
    distance_threshold = float(
        np.quantile(d_val, config.distance_quantile) * config.distance_margin
    )
    n_cls = len(CLASS_NAMES)
    metrics = {
        "train": classification_metrics(_softmax(logit_train / temperature), train.y, n_cls),
        "heldout_uncalibrated": classification_metrics(_softmax(logit_val), val.y, n_cls),
        "heldout": classification_metrics(_softmax(logit_val / temperature), val.y, n_cls),
        "heldout_unknown_rate": float(np.mean(d_val > distance_threshold)),
    }
    unknown = {
        "probability_threshold": config.probability_threshold,
        "distance_threshold": distance_threshold,
        "class_mean": class_mean.tolist(),
        "class_std": class_std.tolist(),
    }
    extra = {
        "seed": seed,
        "config": asdict(config),
        "n_traces": len(traces),
        "windows": {"train": len(train.y), "heldout": len(val.y)},
        "windows_per_class": {c: int(np.sum(windows.y == i)) for i, c in enumerate(CLASS_NAMES)},
    }
    return export_classifier(
        net,
        out_dir,
        fill=fill,
        nominal=nominal,
        window_s=config.window_s,
        temperature=temperature,
        unknown=unknown,
        hidden=config.hidden,
        digest=training_digest(traces),
        metrics=metrics,
        extra=extra,
    )


def export_classifier(
    net: FeatureMLP,
    out_dir: str | Path | None,
    *,
    fill: np.ndarray,
    nominal: NominalModel,
    window_s: float,
    temperature: float,
    unknown: dict[str, Any],
    hidden: tuple[int, ...],
    digest: str,
    metrics: dict[str, Any],
    extra: dict[str, Any],
) -> ClassifierCard:
    """Write ``model.pt2`` (torch.export of ``net``) and ``model_card.json`` to ``out_dir``
    (nothing written when it is None); return the card."""
    net = net.eval()
    batch = torch.export.Dim("batch", min=1, max=1 << 20)
    example = torch.zeros(2, len(FEATURE_NAMES))
    program = torch.export.export(net, (example,), dynamic_shapes={"x": {0: batch}})
    h = hashlib.sha256()
    for name, tensor in sorted(program.state_dict.items()):
        h.update(name.encode())
        h.update(tensor.detach().double().numpy().tobytes())
    center = net.center.double().numpy()
    scale = net.scale.double().numpy()
    card = ClassifierCard(
        kind=KIND,
        inputs=WINDOW_SIGNALS,
        features=FEATURE_NAMES,
        outputs=CLASS_NAMES,
        class_names=CLASS_NAMES,
        scaling={
            f: {"center": float(c), "scale": float(s)}
            for f, c, s in zip(FEATURE_NAMES, center, scale, strict=True)
        },
        feature_fill={f: float(v) for f, v in zip(FEATURE_NAMES, fill, strict=True)},
        sample_time_s=nominal.sample_time_s,
        window_s=float(window_s),
        lookbacks={"window_samples": round(window_s / nominal.sample_time_s)},
        nominal_model_id=nominal.model_id,
        temperature=float(temperature),
        unknown=unknown,
        architecture="mlp",
        hidden=tuple(hidden),
        training_data_digest=digest,
        training_metrics=metrics,
        code_version=code_version(),
        created=datetime.now(UTC).isoformat(timespec="seconds"),
        model_id=f"classifier-mlp-{h.hexdigest()[:12]}",
        extra=extra,
    )
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        torch.export.save(program, out / PROGRAM_FILE)
        (out / CARD_FILE).write_text(card.to_json())
    return card
