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

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numba import njit

from thruster_fdd.core.artifact import CARD_FILE, FORMAT_VERSION, PROGRAM_FILE, load_card_json
from thruster_fdd.core.diagnosis.features import FEATURE_NAMES, WINDOW_SIGNALS, window_features
from thruster_fdd.core.labels import CLASS_NAMES

KIND = "classifier"
"""``model_card.json`` kind of an exported classifier."""


Z_CLIP = 10.0
"""Standardised features are clipped to +-Z_CLIP inside the network (wild inputs stay finite)."""


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
        return softmax(logits / self.card.temperature), _class_distance(x, *self._distance_args)


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
