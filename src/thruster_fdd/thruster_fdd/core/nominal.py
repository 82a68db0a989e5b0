"""Nominal thruster models: the paper's six Table 1 regressors, IQR scaling, export, online use.

Every model maps the inputs ``command`` (normalised, -1..1) and ``voltage`` (V) to the outputs
``rpm`` and ``current`` (A), in IQR-scaled units inside the network. Regressors at sample ``k``
use samples ``k-1, k-2, ...`` only (strictly the past: the prediction of sample ``k`` never sees
anything measured at ``k``).

- ``mlp``: static MLP of the last input sample.
- ``mlp_tdd``: Hammerstein-Wiener style MLP: learnable deadband on the command, a tapped delay
  line of ``input_lags`` input samples, MLP.
- ``narx`` / ``narx_deadband``: MLP (plus a linear skip) of ``input_lags`` past inputs and
  ``output_lags`` past outputs; the deadband variant puts a learnable deadband on the command.
  Series-parallel: past outputs are measured; parallel: past outputs are the model's own
  predictions (free run after an initialisation window of measured samples).
- ``lstm`` / ``gru``: recurrent networks over the input sequence.

Only NARX models are exported (``export_narx``): a ``torch.export`` program (``model.pt2``) that
takes raw past inputs and outputs and returns raw predictions (the scaler is inside the graph),
plus ``model_card.json``. ``NominalModel`` loads an exported directory without training code and
evaluates the program's own weights with numpy (``NarxWeights``) for a per-sample online step; at
load it checks that this fast path reproduces the exported program on probe inputs.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numba import njit
from torch import nn

INPUTS: tuple[str, ...] = ("command", "voltage")
"""Model inputs, in order: normalised command (-1..1), bus voltage (V)."""

OUTPUTS: tuple[str, ...] = ("rpm", "current")
"""Model outputs, in order: shaft speed (rpm), bus current (A)."""

KIND = "nominal"
"""``ModelCard.kind`` of a nominal model."""

MODES: tuple[str, ...] = ("series-parallel", "parallel")
"""NARX configurations: one step ahead from measured past outputs, or free run."""

ARCHITECTURES: tuple[str, ...] = ("mlp", "mlp_tdd", "narx", "narx_deadband", "lstm", "gru")
"""The six regressors of the paper's Table 1."""

NARX_ARCHITECTURES: tuple[str, ...] = ("narx", "narx_deadband")

MIN_SCALE: dict[str, float] = {"command": 0.1, "voltage": 1.0, "rpm": 100.0, "current": 0.5}
"""Floor of each signal's IQR, in its unit: a signal nearly constant in the training data (the
supply voltage of a single-voltage run) must not be blown up into noise of unit size."""

CARD_FILE = "model_card.json"
PROGRAM_FILE = "model.pt2"
FORMAT_VERSION = 1
PROBE_TOLERANCE = 1e-3
"""Largest relative difference (of the output scale) allowed between the numpy fast path and the
exported program on the load-time probe inputs (the program runs in float32)."""


# ---------------------------------------------------------------------------------------------
# IQR scaling


@dataclass(frozen=True)
class IqrScaler:
    """Per-signal robust scaling ``(x - median) / max(IQR, floor)``.

    Attributes
    ----------
    names : tuple of str
        Signal names, one per column.
    center : tuple of float
        Median of each signal in its unit.
    scale : tuple of float
        Interquartile range of each signal (floored by ``MIN_SCALE``), in its unit.
    """

    names: tuple[str, ...]
    center: tuple[float, ...]
    scale: tuple[float, ...]

    def __post_init__(self) -> None:
        if not (len(self.names) == len(self.center) == len(self.scale)):
            raise ValueError("IqrScaler: names, center and scale must have equal lengths")
        if not all(math.isfinite(c) for c in self.center):
            raise ValueError(f"IqrScaler: center must be finite, got {self.center}")
        if not all(math.isfinite(s) and s > 0 for s in self.scale):
            raise ValueError(f"IqrScaler: scale must be finite and > 0, got {self.scale}")

    @classmethod
    def fit(cls, names: tuple[str, ...], x: np.ndarray) -> IqrScaler:
        """Fit on data ``x`` of shape (n, len(names)); NaN rows are ignored."""
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != len(names) or len(x) == 0:
            raise ValueError(f"IqrScaler.fit: expected shape (n, {len(names)}), got {x.shape}")
        q25, q50, q75 = np.nanpercentile(x, [25.0, 50.0, 75.0], axis=0)
        scale = [
            max(float(hi - lo), MIN_SCALE.get(n, 1e-9))
            for n, lo, hi in zip(names, q25, q75, strict=True)
        ]
        return cls(tuple(names), tuple(float(c) for c in q50), tuple(scale))

    def transform(self, x: np.ndarray) -> np.ndarray:
        """Scale ``x`` of shape (..., len(names)) from signal units to scaled units."""
        return (np.asarray(x, dtype=float) - np.asarray(self.center)) / np.asarray(self.scale)

    def inverse(self, z: np.ndarray) -> np.ndarray:
        """Map scaled ``z`` of shape (..., len(names)) back to signal units."""
        return np.asarray(z, dtype=float) * np.asarray(self.scale) + np.asarray(self.center)

    def to_dict(self) -> dict[str, dict[str, float]]:
        """``{signal: {"median": ..., "iqr": ...}}`` for the model card."""
        return {
            n: {"median": c, "iqr": s}
            for n, c, s in zip(self.names, self.center, self.scale, strict=True)
        }

    @classmethod
    def from_dict(cls, names: tuple[str, ...], d: dict[str, Any]) -> IqrScaler:
        """Inverse of ``to_dict`` for the given signal order; ValueError if a signal is missing."""
        missing = [n for n in names if n not in d]
        if missing:
            raise ValueError(f"scaling lacks signal(s) {', '.join(missing)}")
        return cls(
            tuple(names),
            tuple(float(d[n]["median"]) for n in names),
            tuple(float(d[n]["iqr"]) for n in names),
        )


# ---------------------------------------------------------------------------------------------
# Networks (all in scaled units)


@dataclass(frozen=True)
class ModelSpec:
    """Hyperparameters of one regressor.

    Attributes
    ----------
    architecture : str
        One of ``ARCHITECTURES``.
    hidden : tuple of int
        Hidden layer sizes (MLP, NARX) or ``(state size,)`` (LSTM, GRU).
    input_lags : int
        Past input samples seen (``mlp``: 1; recurrent: 1, the state holds the rest).
    output_lags : int
        Past output samples seen (NARX only; 0 otherwise).
    feedback : tuple of str
        Which outputs' past values enter the regressor (NARX only), a subset of ``OUTPUTS`` in
        order. The bus current is quasi-static in duty and speed, so a NARX without its own
        current feedback extrapolates better in free run (docs/nominal_model.md).
    """

    architecture: str
    hidden: tuple[int, ...] = (32,)
    input_lags: int = 10
    output_lags: int = 2
    feedback: tuple[str, ...] = OUTPUTS

    def __post_init__(self) -> None:
        if self.architecture not in ARCHITECTURES:
            raise ValueError(
                f"unknown architecture {self.architecture!r}; expected one of "
                f"{', '.join(ARCHITECTURES)}"
            )
        if not self.hidden or any(h < 1 for h in self.hidden):
            raise ValueError(f"hidden sizes must be >= 1, got {self.hidden}")
        if self.input_lags < 1:
            raise ValueError(f"input_lags must be >= 1, got {self.input_lags}")
        is_narx = self.architecture in NARX_ARCHITECTURES
        if is_narx and self.output_lags < 1:
            raise ValueError(f"a NARX needs output_lags >= 1, got {self.output_lags}")
        if is_narx and (not self.feedback or any(f not in OUTPUTS for f in self.feedback)):
            raise ValueError(
                f"feedback must be a non-empty subset of {OUTPUTS}, got {self.feedback}"
            )
        if is_narx and tuple(f for f in OUTPUTS if f in self.feedback) != self.feedback:
            raise ValueError(f"feedback must list outputs in the order {OUTPUTS}")
        if not is_narx and self.output_lags != 0:
            raise ValueError(f"{self.architecture} has no output feedback: output_lags must be 0")
        if self.architecture in ("mlp", "lstm", "gru") and self.input_lags != 1:
            raise ValueError(f"{self.architecture} takes input_lags = 1")
        if self.architecture in ("lstm", "gru") and len(self.hidden) != 1:
            raise ValueError(f"{self.architecture} takes one state size, got {self.hidden}")

    @property
    def is_narx(self) -> bool:
        """True for the NARX regressors (output feedback)."""
        return self.architecture in NARX_ARCHITECTURES

    @property
    def is_recurrent(self) -> bool:
        """True for LSTM and GRU."""
        return self.architecture in ("lstm", "gru")

    @property
    def has_deadband(self) -> bool:
        """True when the command passes a learnable deadband first."""
        return self.architecture in ("mlp_tdd", "narx_deadband")

    @property
    def feedback_index(self) -> list[int]:
        """Column indices (into ``OUTPUTS``) of the fed-back outputs; empty without feedback."""
        return [OUTPUTS.index(f) for f in self.feedback] if self.output_lags else []

    @property
    def n_regressors(self) -> int:
        """Length of the flattened regressor vector."""
        return 2 * self.input_lags + len(self.feedback_index) * self.output_lags

    @property
    def warmup(self) -> int:
        """Samples needed before the first prediction: ``max(input_lags, output_lags)``."""
        return max(self.input_lags, self.output_lags)


def deadband(command: torch.Tensor, width: torch.Tensor) -> torch.Tensor:
    """Soft-threshold deadband: 0 for ``|command| <= width``, ``command -+ width`` outside."""
    return command - torch.clamp(command, -width, width)


class LagNet(nn.Module):
    """Feed-forward regressor of lagged inputs (and outputs): MLP, MLP-TDD, NARX, NARX-deadband.

    ``forward(u_hist, y_hist)`` takes raw signals, oldest first: ``u_hist`` shape
    (B, input_lags, 2) (command, V), ``y_hist`` shape (B, output_lags, 2) (rpm, A), and returns
    the raw prediction of the next sample, shape (B, 2). The scaler is held as buffers, so an
    exported program is self-contained. ``forward_scaled`` works in scaled units (training).
    """

    def __init__(self, spec: ModelSpec, u_scaler: IqrScaler, y_scaler: IqrScaler) -> None:
        super().__init__()
        if spec.is_recurrent:
            raise ValueError("LagNet is for feed-forward architectures, not LSTM/GRU")
        self.spec = spec
        self.register_buffer("u_center", torch.tensor(u_scaler.center, dtype=torch.float32))
        self.register_buffer("u_scale", torch.tensor(u_scaler.scale, dtype=torch.float32))
        self.register_buffer("y_center", torch.tensor(y_scaler.center, dtype=torch.float32))
        self.register_buffer("y_scale", torch.tensor(y_scaler.scale, dtype=torch.float32))
        n_in = spec.n_regressors
        layers = []
        for h in spec.hidden:
            layers.append(nn.Linear(n_in, h))
            n_in = h
        self.hidden = nn.ModuleList(layers)
        self.out = nn.Linear(n_in, 2)
        self.linear = nn.Linear(spec.n_regressors, 2, bias=False)
        # Deadband width in raw command units (the T100's ESC: 25 us = 0.0625).
        self.deadband_width = nn.Parameter(torch.tensor(0.05), requires_grad=spec.has_deadband)

    def regressor(self, u_hist: torch.Tensor, y_hist: torch.Tensor) -> torch.Tensor:
        """Scaled, flattened regressor vector, shape (B, 2 * (input_lags + output_lags))."""
        if self.spec.has_deadband:
            cmd = deadband(u_hist[..., 0], self.deadband_width.abs())
            u_hist = torch.stack((cmd, u_hist[..., 1]), dim=-1)
        u = (u_hist - self.u_center) / self.u_scale
        parts = [u.flatten(1)]
        if self.spec.output_lags:
            y = (y_hist - self.y_center) / self.y_scale
            parts.append(y[..., self.spec.feedback_index].flatten(1))
        return torch.cat(parts, dim=1)

    def forward_scaled(self, x: torch.Tensor) -> torch.Tensor:
        """Scaled prediction from a scaled regressor ``x`` (B, n_regressors) -> (B, 2)."""
        z = x
        for layer in self.hidden:
            z = torch.tanh(layer(z))
        return self.out(z) + self.linear(x)

    def forward(self, u_hist: torch.Tensor, y_hist: torch.Tensor) -> torch.Tensor:
        """Raw prediction (B, 2) of rpm and current from raw histories (see class docstring)."""
        return self.forward_scaled(self.regressor(u_hist, y_hist)) * self.y_scale + self.y_center


class RecurrentNet(nn.Module):
    """LSTM or GRU over the input sequence; ``forward(u)`` with raw ``u`` shape (B, T, 2) returns
    the raw predictions (B, T, 2), where output ``t`` is the prediction of sample ``t + 1``."""

    def __init__(self, spec: ModelSpec, u_scaler: IqrScaler, y_scaler: IqrScaler) -> None:
        super().__init__()
        if not spec.is_recurrent:
            raise ValueError("RecurrentNet is for lstm / gru")
        self.spec = spec
        self.register_buffer("u_center", torch.tensor(u_scaler.center, dtype=torch.float32))
        self.register_buffer("u_scale", torch.tensor(u_scaler.scale, dtype=torch.float32))
        self.register_buffer("y_center", torch.tensor(y_scaler.center, dtype=torch.float32))
        self.register_buffer("y_scale", torch.tensor(y_scaler.scale, dtype=torch.float32))
        cell = nn.LSTM if spec.architecture == "lstm" else nn.GRU
        self.rnn = cell(2, spec.hidden[0], batch_first=True)
        self.out = nn.Linear(spec.hidden[0], 2)

    def forward_scaled(self, u_scaled: torch.Tensor) -> torch.Tensor:
        """Scaled predictions (B, T, 2) from scaled inputs (B, T, 2)."""
        h, _ = self.rnn(u_scaled)
        return self.out(h)

    def forward(self, u: torch.Tensor) -> torch.Tensor:
        """Raw predictions (B, T, 2) from raw inputs (B, T, 2)."""
        z = self.forward_scaled((u - self.u_center) / self.u_scale)
        return z * self.y_scale + self.y_center


def build_network(spec: ModelSpec, u_scaler: IqrScaler, y_scaler: IqrScaler) -> nn.Module:
    """The torch module of ``spec``: ``LagNet`` or ``RecurrentNet``."""
    if spec.is_recurrent:
        return RecurrentNet(spec, u_scaler, y_scaler)
    return LagNet(spec, u_scaler, y_scaler)


# ---------------------------------------------------------------------------------------------
# Model card


@dataclass(frozen=True)
class ModelCard:
    """The ``model_card.json`` of an exported model (DESIGN.md "Exported model").

    Attributes
    ----------
    kind : str
        ``"nominal"``.
    inputs, outputs : tuple of str
        ``("command", "voltage")`` and ``("rpm", "current")``, in network order.
    scaling : dict
        ``{signal: {"median": float, "iqr": float}}`` in each signal's unit (IQR floored by
        ``MIN_SCALE``); the exported program holds the same constants.
    sample_time_s : float
        Sample time the model was trained at, s.
    lookbacks : dict
        ``{"input": int, "output": int}``: past samples of inputs and outputs in the regressor.
    class_names : tuple of str
        Empty for a nominal model.
    training_data_digest : str
        SHA-256 over the training samples (t, command, voltage, rpm, current).
    training_metrics : dict
        Metrics measured at training (r2 / RMSE per output, train and validation).
    code_version : str
        ``thruster_fdd`` version (and git commit when known) that trained the model.
    created : str
        ISO-8601 UTC time of export.
    model_id : str
        ``nominal-<architecture>-<hash of weights>``.
    mode : str
        ``"series-parallel"`` or ``"parallel"``: how the node runs the NARX for residuals.
    architecture : str
        ``"narx"`` or ``"narx_deadband"``.
    hidden : tuple of int
        Hidden layer sizes (tanh).
    feedback : tuple of str
        Outputs whose past values enter the regressor (``ModelSpec.feedback``).
    format_version : int
        Version of this directory layout.
    """

    kind: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    scaling: dict[str, dict[str, float]]
    sample_time_s: float
    lookbacks: dict[str, int]
    class_names: tuple[str, ...]
    training_data_digest: str
    training_metrics: dict[str, Any]
    code_version: str
    created: str
    model_id: str
    mode: str
    architecture: str
    hidden: tuple[int, ...]
    feedback: tuple[str, ...]
    format_version: int = FORMAT_VERSION
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        """The card as pretty JSON text."""
        return json.dumps(asdict(self), indent=2, sort_keys=False) + "\n"


_CARD_TYPES: dict[str, type | tuple[type, ...]] = {
    "kind": str,
    "inputs": list,
    "outputs": list,
    "scaling": dict,
    "sample_time_s": (int, float),
    "lookbacks": dict,
    "class_names": list,
    "training_data_digest": str,
    "training_metrics": dict,
    "code_version": str,
    "created": str,
    "model_id": str,
    "mode": str,
    "architecture": str,
    "hidden": list,
    "feedback": list,
    "format_version": int,
}


def load_card_json(
    model_dir: str | Path,
    card_types: dict[str, type | tuple[type, ...]],
    kind: str | None = None,
) -> tuple[Path, dict[str, Any]]:
    """Read ``model_dir/model_card.json`` and check it has every field of ``card_types``.

    Shared by the nominal and the classifier card readers, which add their own checks.

    Parameters
    ----------
    model_dir : str or Path
        Exported model folder.
    card_types : dict of str to type
        Required fields and their JSON types (bool is never accepted for a number).
    kind : str or None
        When given, the card's ``kind`` must equal it (checked before the fields).

    Returns
    -------
    (Path, dict)
        The card's path and its content.

    Raises
    ------
    ValueError
        Naming the file and what is wrong: missing, not JSON, not an object, another kind, a
        missing or mistyped field.
    """
    path = Path(model_dir) / CARD_FILE
    if not path.is_file():
        raise ValueError(f"{path}: model card missing")
    try:
        raw = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(raw).__name__}")
    if kind is not None and raw.get("kind") != kind:
        raise ValueError(f"{path}: kind is {raw.get('kind')!r}, expected {kind!r}")
    missing = [k for k in card_types if k not in raw]
    if missing:
        raise ValueError(f"{path}: missing field(s) {', '.join(missing)}")
    for key, typ in card_types.items():
        if not isinstance(raw[key], typ) or isinstance(raw[key], bool):
            raise ValueError(f"{path}: field {key!r} has type {type(raw[key]).__name__}")
    return path, raw


def read_card(model_dir: str | Path) -> ModelCard:
    """Read and validate ``model_dir/model_card.json``.

    Raises
    ------
    ValueError
        Naming the file and what is wrong: missing, not JSON, a missing or mistyped field.
    """
    path, raw = load_card_json(model_dir, _CARD_TYPES)
    unknown = sorted(set(raw) - set(_CARD_TYPES) - {"extra"})
    if unknown:
        raise ValueError(f"{path}: unknown field(s) {', '.join(unknown)}")
    lookbacks = raw["lookbacks"]
    if set(lookbacks) != {"input", "output"} or not all(
        isinstance(v, int) and v >= 0 for v in lookbacks.values()
    ):
        raise ValueError(
            f"{path}: lookbacks must be {{'input': int, 'output': int}}, got {lookbacks}"
        )
    return ModelCard(
        kind=raw["kind"],
        inputs=tuple(raw["inputs"]),
        outputs=tuple(raw["outputs"]),
        scaling=raw["scaling"],
        sample_time_s=float(raw["sample_time_s"]),
        lookbacks=dict(lookbacks),
        class_names=tuple(raw["class_names"]),
        training_data_digest=raw["training_data_digest"],
        training_metrics=raw["training_metrics"],
        code_version=raw["code_version"],
        created=raw["created"],
        model_id=raw["model_id"],
        mode=raw["mode"],
        architecture=raw["architecture"],
        hidden=tuple(int(h) for h in raw["hidden"]),
        feedback=tuple(raw["feedback"]),
        format_version=raw["format_version"],
        extra=dict(raw.get("extra", {})),
    )


def check_nominal_card(card: ModelCard, path: Path) -> None:
    """ValueError naming ``path`` and what differs from a nominal NARX card."""
    expected = {"kind": KIND, "inputs": INPUTS, "outputs": OUTPUTS, "class_names": ()}
    for key, want in expected.items():
        got = getattr(card, key)
        if got != want:
            raise ValueError(f"{path}: {key} is {got!r}, expected {want!r}")
    if card.format_version != FORMAT_VERSION:
        raise ValueError(
            f"{path}: format_version is {card.format_version}, expected {FORMAT_VERSION}"
        )
    if card.mode not in MODES:
        raise ValueError(f"{path}: mode is {card.mode!r}, expected one of {', '.join(MODES)}")
    if card.architecture not in NARX_ARCHITECTURES:
        raise ValueError(
            f"{path}: architecture is {card.architecture!r}, expected one of "
            f"{', '.join(NARX_ARCHITECTURES)}"
        )
    if not (math.isfinite(card.sample_time_s) and card.sample_time_s > 0):
        raise ValueError(f"{path}: sample_time_s must be > 0, got {card.sample_time_s}")
    if card.lookbacks["input"] < 1 or card.lookbacks["output"] < 1:
        raise ValueError(f"{path}: a NARX needs input and output lookbacks >= 1")


# ---------------------------------------------------------------------------------------------
# Export


def data_digest(traces_arrays: list[np.ndarray]) -> str:
    """SHA-256 (hex) over float64 sample arrays, each shape (n, k), in order."""
    h = hashlib.sha256()
    for arr in traces_arrays:
        h.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
    return h.hexdigest()


def code_version() -> str:
    """``thruster_fdd <version>`` of the installed package."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"thruster_fdd {version('thruster_fdd')}"
    except PackageNotFoundError:
        return "thruster_fdd unknown"


def export_narx(
    net: LagNet,
    out_dir: str | Path,
    *,
    mode: str,
    sample_time_s: float,
    training_data_digest: str,
    training_metrics: dict[str, Any],
    extra: dict[str, Any] | None = None,
) -> ModelCard:
    """Export a trained NARX to ``out_dir`` (``model.pt2`` + ``model_card.json``).

    Parameters
    ----------
    net : LagNet
        A trained ``narx`` or ``narx_deadband`` network.
    out_dir : str or Path
        Directory to write (created; existing card/program replaced).
    mode : str
        Configuration the node uses for residuals (``MODES``).
    sample_time_s : float
        Sample time of the training data, s.
    training_data_digest : str
        ``data_digest`` of the training samples.
    training_metrics : dict
        Metrics to record in the card.
    extra : dict or None
        Further JSON-able facts for the card (training options).

    Returns
    -------
    ModelCard
        The card written.
    """
    spec = net.spec
    if not spec.is_narx:
        raise ValueError(f"only NARX models are exported, got {spec.architecture}")
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    net = net.eval()
    u_ex = torch.zeros(2, spec.input_lags, 2)
    y_ex = torch.zeros(2, spec.output_lags, 2)
    batch = torch.export.Dim("batch", min=1, max=1 << 20)
    program = torch.export.export(
        net, (u_ex, y_ex), dynamic_shapes={"u_hist": {0: batch}, "y_hist": {0: batch}}
    )
    torch.export.save(program, out / PROGRAM_FILE)
    weights = NarxWeights.from_state_dict(program.state_dict, spec)
    u_scaler = IqrScaler(INPUTS, *_pair(net.u_center, net.u_scale))
    y_scaler = IqrScaler(OUTPUTS, *_pair(net.y_center, net.y_scale))
    scaling = {**u_scaler.to_dict(), **y_scaler.to_dict()}
    card = ModelCard(
        kind=KIND,
        inputs=INPUTS,
        outputs=OUTPUTS,
        scaling=scaling,
        sample_time_s=float(sample_time_s),
        lookbacks={"input": spec.input_lags, "output": spec.output_lags},
        class_names=(),
        training_data_digest=training_data_digest,
        training_metrics=training_metrics,
        code_version=code_version(),
        created=datetime.now(UTC).isoformat(timespec="seconds"),
        model_id=f"nominal-{spec.architecture}-{weights.digest()[:12]}",
        mode=mode,
        architecture=spec.architecture,
        hidden=spec.hidden,
        feedback=spec.feedback,
        extra=dict(extra or {}),
    )
    (out / CARD_FILE).write_text(card.to_json())
    return card


def _pair(center: torch.Tensor, scale: torch.Tensor) -> tuple[tuple[float, ...], ...]:
    return tuple(float(v) for v in center), tuple(float(v) for v in scale)


# ---------------------------------------------------------------------------------------------
# Fast path: the exported program's own weights evaluated with numpy


@dataclass(frozen=True)
class NarxWeights:
    """The weights of an exported NARX as float64 numpy arrays (the program's own tensors).

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
    def from_state_dict(cls, state: dict[str, torch.Tensor], spec: ModelSpec) -> NarxWeights:
        """Pick the tensors of ``LagNet`` out of a (exported program's) state dict.

        Raises
        ------
        ValueError
            If a tensor is missing or its shape does not match ``spec``.
        """

        def get(name: str, shape: tuple[int, ...]) -> np.ndarray:
            if name not in state:
                raise ValueError(f"tensor {name!r} missing from the program")
            arr = state[name].detach().to(torch.float64).numpy().copy()
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
            raise ValueError(
                f"program has {len(extra) // 2} hidden layers, card {len(spec.hidden)}"
            )
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


# ---------------------------------------------------------------------------------------------
# The loaded model: online step and batch predict


class NominalModel:
    """An exported nominal NARX, loaded without training code: online ``step``, batch ``predict``.

    Attributes
    ----------
    card : ModelCard
    model_id : str
    sample_time_s : float
    warmup_samples : int
        Samples fed before the first prediction (``max`` of the lookbacks). In parallel mode
        these measured samples are the free run's initialisation window.
    mode : str
    program : torch.export.ExportedProgram
        The loaded artifact (its weights are what ``step``/``predict`` evaluate).
    """

    def __init__(self, card: ModelCard, program: Any, weights: NarxWeights) -> None:
        self.card = card
        self.model_id = card.model_id
        self.sample_time_s = card.sample_time_s
        self.mode = card.mode
        self.program = program
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
        """Load ``model_dir`` (``model_card.json`` + ``model.pt2``).

        Raises
        ------
        ValueError
            Naming the file and what is wrong or differs: missing directory or files, corrupt
            card or program, wrong kind / inputs / outputs / mode, program weights that do not
            match the card (lookbacks, hidden sizes, scaling), or a program whose output the
            fast path does not reproduce.
        """
        model_dir = Path(model_dir)
        if not model_dir.is_dir():
            raise ValueError(f"{model_dir}: model directory missing")
        card = read_card(model_dir)
        card_path = model_dir / CARD_FILE
        check_nominal_card(card, card_path)
        try:
            spec = ModelSpec(
                card.architecture,
                card.hidden,
                card.lookbacks["input"],
                card.lookbacks["output"],
                card.feedback,
            )
            u_scaler = IqrScaler.from_dict(INPUTS, card.scaling)
            y_scaler = IqrScaler.from_dict(OUTPUTS, card.scaling)
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{card_path}: {exc}") from exc
        prog_path = model_dir / PROGRAM_FILE
        if not prog_path.is_file():
            raise ValueError(f"{prog_path}: exported program missing")
        try:
            program = torch.export.load(prog_path)
        except Exception as exc:
            raise ValueError(f"{prog_path}: not a loadable torch export program ({exc})") from exc
        try:
            weights = NarxWeights.from_state_dict(program.state_dict, spec)
        except ValueError as exc:
            raise ValueError(f"{prog_path}: does not match {CARD_FILE}: {exc}") from exc
        for name, scaler, center, scale in (
            ("inputs", u_scaler, weights.u_center, weights.u_scale),
            ("outputs", y_scaler, weights.y_center, weights.y_scale),
        ):
            if not (
                np.allclose(center, scaler.center, rtol=1e-6) and np.allclose(scale, scaler.scale)
            ):
                raise ValueError(
                    f"{prog_path}: scaling of {name} differs from {CARD_FILE}: program "
                    f"center {center.tolist()} scale {scale.tolist()}, card center "
                    f"{list(scaler.center)} scale {list(scaler.scale)}"
                )
        _check_fast_path(program, weights, prog_path)
        model = cls(card, program, weights)
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
            out[w:] = free_run(self.weights.predict, u, y[:w], self._nu, self._ny)
        return out[:, 0], out[:, 1]


def free_run(predict_fn: Any, u: np.ndarray, y_init: np.ndarray, nu: int, ny: int) -> np.ndarray:
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


def _check_fast_path(program: Any, weights: NarxWeights, path: Path) -> None:
    """ValueError if the numpy fast path does not reproduce ``program`` on probe inputs."""
    rng = np.random.default_rng(0)
    spec = weights.spec
    u = weights.u_center + weights.u_scale * rng.normal(size=(8, spec.input_lags, 2))
    y = weights.y_center + weights.y_scale * rng.normal(size=(8, spec.output_lags, 2))
    try:
        with torch.inference_mode():
            ref = (
                program.module()(
                    torch.tensor(u, dtype=torch.float32), torch.tensor(y, dtype=torch.float32)
                )
                .double()
                .numpy()
            )
    except Exception as exc:
        raise ValueError(f"{path}: the program fails on (B, {spec.input_lags}, 2), "
                         f"(B, {spec.output_lags}, 2) inputs ({exc})") from exc  # fmt: skip
    fast = weights.predict(u, y)
    err = np.max(np.abs(fast - ref) / weights.y_scale)
    if not err <= PROBE_TOLERANCE:
        raise ValueError(
            f"{path}: the program's graph differs from a {spec.architecture} with these weights "
            f"(max scaled difference {err:.3g})"
        )
