"""An exported nominal NARX loaded for use: online ``step`` and batch ``predict``.

``NominalModel`` loads an exported folder without torch or training code: the card, then the
weights file after checking every file's digest (``artifact.load_weights``), evaluated with numpy
(``NarxWeights``) and per sample with a compiled step (``_narx_step``). That these weights
reproduce the exported program is checked at export (``nominal.export``), where torch is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from thruster_fdd.core.artifact import WEIGHTS_FILE, data_digest, load_weights
from thruster_fdd.core.errors import ModelMismatchError
from thruster_fdd.core.nominal.card import NominalCard, read_nominal_card
from thruster_fdd.core.nominal.spec import INPUTS, OUTPUTS, ModelSpec


@dataclass(frozen=True)
class NarxWeights:
    """The weights of an exported NARX as float64 numpy arrays (the network's own tensors).

    ``predict(u_hist, y_hist)`` computes exactly ``LagNet.forward`` (tanh MLP + linear skip,
    optional deadband, scaler) for raw histories of shape (B, input_lags, 2), (B, output_lags, 2).
    """

    spec: ModelSpec
    u_center: np.ndarray
    u_scale: np.ndarray
    y_center: np.ndarray
    y_scale: np.ndarray
    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    out_w: np.ndarray
    out_b: np.ndarray
    linear_w: np.ndarray
    deadband_width: float

    @classmethod
    def from_arrays(cls, state: Mapping[str, np.ndarray], spec: ModelSpec) -> NarxWeights:
        """Pick the tensors of ``LagNet`` out of its state dict as numpy arrays, by name.

        Raises
        ------
        ValueError
            If an array is missing or its shape does not match ``spec``.
        """

        def get(name: str, shape: tuple[int, ...]) -> np.ndarray:
            if name not in state:
                raise ValueError(f"tensor {name!r} missing")
            arr = np.array(state[name], dtype=np.float64)
            if arr.shape != shape:
                raise ValueError(f"tensor {name!r} has shape {arr.shape}, expected {shape}")
            return arr

        n_reg = spec.n_regressors
        layers = []
        n_in = n_reg
        for i, h in enumerate(spec.hidden):
            layers.append((get(f"hidden.{i}.weight", (h, n_in)), get(f"hidden.{i}.bias", (h,))))
            n_in = h
        extra = sorted(k for k in state if k.startswith("hidden.") and k.count(".") == 2)
        if len(extra) != 2 * len(spec.hidden):
            raise ValueError(f"{len(extra) // 2} hidden layers, the card says {len(spec.hidden)}")
        return cls(
            spec=spec,
            u_center=get("u_center", (2,)),
            u_scale=get("u_scale", (2,)),
            y_center=get("y_center", (2,)),
            y_scale=get("y_scale", (2,)),
            layers=tuple(layers),
            out_w=get("out.weight", (2, n_in)),
            out_b=get("out.bias", (2,)),
            linear_w=get("linear.weight", (2, n_reg)),
            deadband_width=float(abs(get("deadband_width", ()))) if spec.has_deadband else 0.0,
        )

    def digest(self) -> str:
        """SHA-256 (hex) over every weight, in a fixed order."""
        arrays = [self.u_center, self.u_scale, self.y_center, self.y_scale]
        for w, b in self.layers:
            arrays += [w, b]
        arrays += [self.out_w, self.out_b, self.linear_w, np.array([self.deadband_width])]
        return data_digest([a.reshape(1, -1) for a in arrays])

    def predict(self, u_hist: np.ndarray, y_hist: np.ndarray) -> np.ndarray:
        """Raw predictions (B, 2) from raw histories (B, input_lags, 2), (B, output_lags, 2)."""
        if self.spec.has_deadband:
            cmd = u_hist[..., 0]
            cmd = cmd - np.clip(cmd, -self.deadband_width, self.deadband_width)
            u_hist = np.stack((cmd, u_hist[..., 1]), axis=-1)
        b = u_hist.shape[0]
        u = ((u_hist - self.u_center) / self.u_scale).reshape(b, -1)
        y = ((y_hist - self.y_center) / self.y_scale)[..., self.spec.feedback_index].reshape(b, -1)
        x = np.concatenate((u, y), axis=1)
        z = x
        for w, bias in self.layers:
            z = np.tanh(z @ w.T + bias)
        return (z @ self.out_w.T + self.out_b + x @ self.linear_w.T) * self.y_scale + self.y_center

    def kernel_args(self) -> tuple:
        """The weights as ``_narx_step`` takes them (a tuple of arrays and the deadband)."""
        return (
            self.layers,
            self.out_w,
            self.out_b,
            self.linear_w,
            self.u_center,
            self.u_scale,
            self.y_center,
            self.y_scale,
            self.deadband_width if self.spec.has_deadband else 0.0,
        )


@njit(cache=True)
def _narx_step(
    x: np.ndarray,
    n_u: int,
    feedback_index: np.ndarray,
    weights: tuple,
    sample: tuple[float, float, float, float],
    predict: bool,
    parallel: bool,
) -> tuple[float, float]:
    """One online step of a NARX, compiled: predict from the regressor vector ``x``, then shift
    this sample into it (in place).

    ``x`` (n_regressors,) holds the scaled inputs of the last ``n_u / 2`` samples, then the
    scaled feedback of the last outputs, laid out as ``NarxWeights.predict`` lays them out.
    ``weights`` is ``NarxWeights.kernel_args()``; ``sample`` is (command -1..1, voltage V, rpm,
    current A). Returns the raw (rpm, current) prediction when ``predict``, else NaNs; in
    ``parallel`` mode the prediction, not the measurement, enters the feedback. The same
    arithmetic as ``predict`` (up to summation order) without the dispatch of some twenty
    numpy calls per sample.
    """
    layers, out_w, out_b, linear_w, u_center, u_scale, y_center, y_scale, deadband = weights
    command, voltage, rpm, current = sample
    pred = (np.nan, np.nan)
    if predict:
        h = x
        for layer in layers:
            weight, bias = layer
            z = np.empty(bias.shape[0])
            for o in range(bias.shape[0]):
                acc = bias[o]
                for i in range(h.shape[0]):
                    acc += weight[o, i] * h[i]
                z[o] = np.tanh(acc)
            h = z
        out = np.empty(2)
        for j in range(2):
            acc = out_b[j]
            for i in range(h.shape[0]):
                acc += out_w[j, i] * h[i]
            for i in range(x.shape[0]):
                acc += linear_w[j, i] * x[i]
            out[j] = acc * y_scale[j] + y_center[j]
        pred = (out[0], out[1])
    if deadband > 0.0:
        command -= min(max(command, -deadband), deadband)
    for i in range(n_u - 2):
        x[i] = x[i + 2]
    x[n_u - 2] = (command - u_center[0]) / u_scale[0]
    x[n_u - 1] = (voltage - u_center[1]) / u_scale[1]
    y = pred if predict and parallel else (rpm, current)
    n_fb = feedback_index.shape[0]
    for i in range(n_u, x.shape[0] - n_fb):
        x[i] = x[i + n_fb]
    for k in range(n_fb):
        idx = feedback_index[k]
        x[x.shape[0] - n_fb + k] = (y[idx] - y_center[idx]) / y_scale[idx]
    return pred


class NominalModel:
    """An exported nominal NARX, loaded without training code: online ``step``, batch ``predict``.

    Attributes
    ----------
    card : NominalCard
    model_id : str
    sample_time_s : float
    warmup_samples : int
        Samples fed before the first prediction (``max`` of the lookbacks). In parallel mode
        these measured samples are the free run's initialisation window.
    mode : str
    program : torch.export.ExportedProgram
    weights : NarxWeights
        What ``step`` and ``predict`` evaluate.
    """

    def __init__(self, card: NominalCard, weights: NarxWeights) -> None:
        self.card = card
        self.model_id = card.model_id
        self.sample_time_s = card.sample_time_s
        self.mode = card.mode
        self.weights = weights
        self._nu = card.lookbacks["input"]
        self._ny = card.lookbacks["output"]
        self.warmup_samples = max(self._nu, self._ny)
        # The regressor vector of the next prediction, kept up to date sample by sample: the
        # scaled inputs of the last ``input`` samples, then the scaled feedback of the last
        # ``output`` outputs (measured, or in parallel mode the model's own).
        self._x = np.zeros(weights.spec.n_regressors)
        self._feedback_index = np.array(weights.spec.feedback_index, dtype=np.int64)
        self._kernel_args = weights.kernel_args()
        self._seen = 0

    @classmethod
    def load(cls, model_dir: str | Path) -> NominalModel:
        """Load an exported folder (``model_card.json`` + the files it lists).

        Raises
        ------
        ModelMismatchError
            Naming the file and what is wrong or differs: missing folder or files, a file whose
            digest differs from the card's, a corrupt card or weights file, wrong kind / inputs /
            outputs / mode, weights that do not match the card (lookbacks, hidden sizes,
            scaling).
        """
        model_dir = Path(model_dir)
        if not model_dir.is_dir():
            raise ModelMismatchError(f"{model_dir}: model directory missing")
        card = read_nominal_card(model_dir)
        arrays = load_weights(model_dir, card)
        spec = ModelSpec(
            card.architecture,
            card.hidden,
            card.lookbacks["input"],
            card.lookbacks["output"],
            card.feedback,
        )
        path = model_dir / WEIGHTS_FILE
        try:
            weights = NarxWeights.from_arrays(arrays, spec)
        except ValueError as exc:
            raise ModelMismatchError(f"{path}: does not match the card: {exc}") from exc
        for name, signals, center, scale in (
            ("inputs", INPUTS, weights.u_center, weights.u_scale),
            ("outputs", OUTPUTS, weights.y_center, weights.y_scale),
        ):
            want_center, want_scale = card.scaling_of(signals)
            if not (np.allclose(center, want_center, rtol=1e-6) and np.allclose(scale, want_scale)):
                raise ModelMismatchError(
                    f"{path}: scaling of {name} differs from the card: weights center "
                    f"{center.tolist()} scale {scale.tolist()}, card center "
                    f"{want_center.tolist()} scale {want_scale.tolist()}"
                )
        model = cls(card, weights)
        # Compile (or load from numba's cache) the online step now, not at the first sample.
        model.step(0.0, 15.0, 0.0, 0.0)
        model.reset()
        return model

    def reset(self) -> None:
        """Forget the history: the next ``warmup_samples`` samples refill the lookback."""
        self._seen = 0

    def step(
        self, command: float, voltage: float, rpm: float, current: float
    ) -> tuple[float, float] | None:
        """Feed one telemetry sample; predict it from the past only.

        Parameters
        ----------
        command : float
            Normalised command of this sample (-1..1).
        voltage : float
            Bus voltage, V.
        rpm, current : float
            Measured shaft speed (rpm) and bus current (A) of this sample.

        Returns
        -------
        (rpm, current) or None
            Prediction of this sample's rpm and current (A) made from earlier samples only;
            None while the lookback fills (the first ``warmup_samples`` samples after a reset).
            In parallel mode the output history holds the model's own predictions after that.

        Raises
        ------
        ValueError
            If a value is not finite (the history is left unchanged).
        """
        if not all(math.isfinite(v) for v in (command, voltage, rpm, current)):
            raise ValueError(
                f"non-finite sample: command={command}, voltage={voltage}, rpm={rpm}, "
                f"current={current}"
            )
        predict = self._seen >= self.warmup_samples
        pred = _narx_step(
            self._x,
            2 * self._nu,
            self._feedback_index,
            self._kernel_args,
            (float(command), float(voltage), float(rpm), float(current)),
            predict,
            self.mode == "parallel",
        )
        self._seen += 1
        return pred if predict else None

    def predict(
        self, command: np.ndarray, voltage: np.ndarray, rpm: np.ndarray, current: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Predict a whole trace as ``step`` would from a reset state (the state is untouched).

        Parameters
        ----------
        command, voltage, rpm, current : np.ndarray, shape (n,)
            Samples at the model's sample time (-1..1, V, rpm, A).

        Returns
        -------
        (rpm, current) : tuple of np.ndarray, each shape (n,)
            Predictions; NaN for the first ``warmup_samples`` samples.

        Raises
        ------
        ValueError
            If shapes differ or a value is not finite.
        """
        arrays = [np.asarray(a, dtype=float) for a in (command, voltage, rpm, current)]
        n = len(arrays[0])
        if any(a.shape != (n,) for a in arrays):
            raise ValueError(
                f"predict: inputs must be 1-D of equal length, got {[a.shape for a in arrays]}"
            )
        if not all(np.all(np.isfinite(a)) for a in arrays):
            raise ValueError("predict: inputs must be finite")
        u = np.stack(arrays[:2], axis=1)
        y = np.stack(arrays[2:], axis=1)
        out = np.full((n, 2), np.nan)
        w = self.warmup_samples
        if n <= w:
            return out[:, 0], out[:, 1]
        if self.mode == "series-parallel":
            idx = np.arange(w, n)
            u_hist = u[idx[:, None] - np.arange(self._nu, 0, -1)]
            y_hist = y[idx[:, None] - np.arange(self._ny, 0, -1)]
            out[w:] = self.weights.predict(u_hist, y_hist)
        else:
            out[w:] = narx_free_run(self.weights.predict, u, y[:w], self._nu, self._ny)
        return out[:, 0], out[:, 1]


def narx_free_run(
    predict_fn: Callable[[np.ndarray, np.ndarray], np.ndarray],
    u: np.ndarray,
    y_init: np.ndarray,
    nu: int,
    ny: int,
) -> np.ndarray:
    """Parallel (free-run) simulation of a NARX from an initialisation window.

    Parameters
    ----------
    predict_fn : callable
        ``(u_hist (1, nu, 2), y_hist (1, ny, 2)) -> (1, 2)`` raw one-step predictor.
    u : np.ndarray, shape (n, 2)
        Raw inputs (command, V) of the whole trace.
    y_init : np.ndarray, shape (w, 2)
        Measured outputs of the first ``w = max(nu, ny)`` samples.

    Returns
    -------
    np.ndarray, shape (n - w, 2)
        Predictions of samples ``w .. n-1``, each fed back as a past output.
    """
    w = max(nu, ny)
    n = len(u)
    y = np.empty((n, 2))
    y[:w] = y_init
    for k in range(w, n):
        y[k] = predict_fn(u[None, k - nu : k], y[None, k - ny : k])[0]
    return y[w:]
