"""Training, calibration and export of the window classifier (torch; never imported on the
vehicle).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.optimize import minimize_scalar
from torch import nn
from tqdm import tqdm

from thruster_fdd.core.artifact import (
    CARD_FILE,
    PROGRAM_FILE,
    WEIGHTS_FILE,
    code_version,
    file_sha256,
    scaling_entries,
    weights_bytes,
)
from thruster_fdd.core.atomic import replaced_dir
from thruster_fdd.core.diagnosis.coverage import MAX_POINTS, OPERATING_POINT, RESOLUTION, Coverage
from thruster_fdd.core.diagnosis.features import FEATURE_NAMES, WINDOW_SIGNALS
from thruster_fdd.core.diagnosis.model import (
    COVERAGE_ARRAY,
    KIND,
    Z_CLIP,
    ClassifierCard,
    ClassifierModel,
    mlp_forward,
    mlp_layers,
    softmax,
)
from thruster_fdd.core.diagnosis.stream import EXCITATION_RANGE, WindowFeaturizer
from thruster_fdd.core.errors import BadInputError, ModelMismatchError
from thruster_fdd.core.labels import CLASS_NAMES, FAULT_CLASSES
from thruster_fdd.core.nominal.residuals import ResidualStream
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.diagnosis.metrics import (
    classification_metrics,
    expected_calibration_error,
    reliability,
)
from thruster_fdd_shore.core.nominal.export import state_arrays

DEFAULT_WINDOW_S = 20.0
"""Window length, s: 20 s beat 10 s on unseen units (docs/diagnosis.md)."""


STD_FLOOR = 0.05
"""Floor of a class's per-feature std in standardised units (the distance's denominator)."""


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
    holdout_units : int
        With traces of >= 2 units (``Trace.thruster_id``), every this-many-th unit (at least
        one) is held out whole: its windows calibrate the probabilities, the unknown distance
        and the coverage threshold, so that they hold on units the network was not fitted to.
    coverage_quantile : float
        Quantile of the held-out windows' distance to the training region that sets the
        coverage threshold (``diagnosis.coverage``).
    min_band_accuracy : float
        Accuracy (0..1) with which the held-out windows of a band of mean |command| must be
        told healthy from faulty for the band to give evidence (``evidence_floor``).
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
    holdout_units: int = 3
    coverage_quantile: float = 0.99
    min_band_accuracy: float = 0.95


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
    point : np.ndarray, shape (m, 4)
        Operating point of each window (``coverage.OPERATING_POINT``).
    """

    x: np.ndarray
    y: np.ndarray
    trace: np.ndarray
    t_start: np.ndarray
    t_end: np.ndarray
    point: np.ndarray

    def subset(self, mask: np.ndarray) -> WindowSet:
        """The windows where ``mask`` (m,) is True."""
        return WindowSet(
            self.x[mask],
            self.y[mask],
            self.trace[mask],
            self.t_start[mask],
            self.t_end[mask],
            self.point[mask],
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
    xs, ys, ids, t0s, t1s, points = [], [], [], [], [], []
    index = {c: i for i, c in enumerate(CLASS_NAMES)}
    for k, tr in enumerate(tqdm(traces, desc="window features", disable=not progress)):
        labels = tr.sample_labels()
        if labels is None:
            name = tr.thruster_id or f"#{k}"
            raise BadInputError(f"trace {name} has no condition column or labels to train on")
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
            t0, t1, f, point = out
            lo, hi = np.searchsorted(tr.t, [t0, t1], side="left")
            window_labels = set(labels[lo : hi + 1].tolist())
            if len(window_labels) != 1:
                continue
            xs.append(f)
            ys.append(index[window_labels.pop()])
            ids.append(k)
            t0s.append(t0)
            t1s.append(t1)
            points.append(point)
    if not xs:
        raise BadInputError(
            f"no trace is long enough for one {window_s:g} s window of valid samples"
        )
    return WindowSet(
        np.asarray(xs),
        np.asarray(ys),
        np.asarray(ids),
        np.asarray(t0s),
        np.asarray(t1s),
        np.asarray(points),
    )


def holdout_mask(
    windows: WindowSet, traces: list[Trace], config: ClassifierConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Held-out (calibration) and dropped windows, each a bool mask (m,).

    With traces of >= 2 units, whole units are held out (``holdout_units``). Otherwise whole
    traces are held out when a class has >= 3 traces, else each trace's last
    ``holdout_fraction``; with the time split, windows across the split are dropped.
    """
    held = np.zeros(len(windows.y), dtype=bool)
    dropped = np.zeros(len(windows.y), dtype=bool)
    units = sorted({tr.thruster_id for tr in traces if tr.thruster_id})
    if len(units) >= 2 and all(tr.thruster_id for tr in traces):
        chosen = set(units[config.holdout_units - 1 :: config.holdout_units] or units[-1:])
        by_trace = np.array([traces[k].thruster_id in chosen for k in range(len(traces))])
        return by_trace[windows.trace], dropped
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
        p = softmax(logits / math.exp(log_t))
        return float(-np.mean(np.log(p[np.arange(len(y)), y] + 1e-12)))

    res = minimize_scalar(nll, bounds=(-3.0, 3.0), method="bounded")
    return float(math.exp(res.x))


def training_coverage(
    train: WindowSet, held: WindowSet, quantile: float
) -> tuple[Coverage, dict[str, Any]]:
    """The coverage of the training windows' operating points, its threshold the ``quantile``
    of the held-out windows' distance (at least one resolution unit), and the card entry."""
    rng = np.random.default_rng(0)
    points = train.point
    if len(points) > MAX_POINTS:
        points = points[np.sort(rng.choice(len(points), MAX_POINTS, replace=False))]
    resolution = np.array([RESOLUTION[name] for name in OPERATING_POINT])
    probe = Coverage(points=points / resolution, resolution=resolution, threshold=math.inf)
    held_distance = probe.distance(held.point)
    threshold = max(float(np.quantile(held_distance, quantile)), 1.0)
    coverage = Coverage(points=points / resolution, resolution=resolution, threshold=threshold)
    entry = {
        "coordinates": list(OPERATING_POINT),
        "resolution": resolution.tolist(),
        "threshold": threshold,
        "quantile": quantile,
        "summary": coverage.summary(),
    }
    return coverage, entry


BAND_WIDTH = RESOLUTION["command_abs_mean"] / 2.0
"""Width of the bands of mean |command| whose held-out accuracy sets the evidence floor."""


def evidence_floor(
    command_abs: np.ndarray, fault_p: np.ndarray, is_fault: np.ndarray, min_accuracy: float
) -> dict[str, Any]:
    """The mean |command| from which held-out windows are told healthy from faulty reliably.

    A fault shows as a change of the load the propeller puts on the motor, and the load grows
    with the square of the speed: at small commands it is a few per cent of full load, so a
    unit's own offsets (gains, zero offsets, deadband) outweigh what a fault changes, and units
    the network was not fitted to are told apart no better than by chance. Where that happens
    depends on the thruster type and on what the training data hold, so it is measured on the
    held-out units: their windows are put in bands of ``BAND_WIDTH``, and a band's accuracy is
    the share of its windows whose fault probability (fault classes together) is on the right
    side of 1/2, counted as ``(right + 1) / (windows + 2)`` so that a band of a few windows
    proves nothing. The floor is the lower edge of the lowest band that reaches
    ``min_accuracy``; windows below it give no evidence (``DiagnosisStream``).

    Parameters
    ----------
    command_abs : np.ndarray, shape (m,)
        Mean |command| of each held-out window that the rotor turned in (-1..1 scale).
    fault_p : np.ndarray, shape (m,)
        Its calibrated probability of the fault classes together.
    is_fault : np.ndarray, shape (m,)
        Whether its true class is a fault.
    min_accuracy : float
        Accuracy a band must reach, 0..1.

    Returns
    -------
    dict
        The card entry ``{"min_command_abs", "min_accuracy", "band_width", "bands"}``:
        ``min_command_abs`` is None when no band reaches the accuracy (no window gives
        evidence); ``bands`` lists ``[lower edge, windows, accuracy]`` of every band with a
        window.
    """
    band = np.floor(np.clip(command_abs, 0.0, 1.0) / BAND_WIDTH + 1e-9).astype(int)
    right = (fault_p > 0.5) == is_fault
    bands = []
    floor = None
    for b in np.unique(band):
        mine = band == b
        accuracy = round((float(right[mine].sum()) + 1.0) / (float(mine.sum()) + 2.0), 4)
        lower = round(float(b) * BAND_WIDTH, 6)
        bands.append([lower, int(mine.sum()), accuracy])
        if floor is None and accuracy >= min_accuracy:
            floor = lower
    return {
        "min_command_abs": floor,
        "min_accuracy": min_accuracy,
        "band_width": BAND_WIDTH,
        "bands": bands,
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
    extra: dict[str, Any] | None = None,
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
    extra : dict or None
        Further JSON-able facts for the card's ``extra`` (e.g. the training files' digests).

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
        raise BadInputError("no traces to train on")
    nominal = NominalModel.load(nominal_dir)
    windows = trace_windows(
        traces, nominal, window_s=config.window_s, hop_s=config.hop_s, progress=progress
    )
    held, dropped = holdout_mask(windows, traces, config)
    train, val = windows.subset(~dropped & ~held), windows.subset(~dropped & held)
    missing = [c for i, c in enumerate(CLASS_NAMES) if not np.any(train.y == i)]
    if missing:
        raise BadInputError(f"no training window of class(es) {', '.join(missing)}")
    if len(val.y) == 0:
        raise BadInputError("no held-out window for calibration; give longer or more traces")
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
    coverage, coverage_entry = training_coverage(train, val, config.coverage_quantile)
    p_val = softmax(logit_val / temperature)
    faults = np.array([c in FAULT_CLASSES for c in CLASS_NAMES])
    turning = x_val[:, FEATURE_NAMES.index("active_fraction")] >= EXCITATION_RANGE[0]
    coverage_entry["evidence_floor"] = evidence_floor(
        val.point[turning, OPERATING_POINT.index("command_abs_mean")],
        p_val[turning][:, faults].sum(axis=1),
        faults[val.y[turning]],
        config.min_band_accuracy,
    )
    calibration = {
        "units": sorted({traces[k].thruster_id for k in np.unique(val.trace)} - {""}),
        "windows": len(val.y),
        "ece_uncalibrated": expected_calibration_error(softmax(logit_val), val.y),
        "ece": expected_calibration_error(p_val, val.y),
        "reliability": reliability(p_val, val.y),
    }
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
        "train": classification_metrics(softmax(logit_train / temperature), train.y, n_cls),
        "heldout_uncalibrated": classification_metrics(softmax(logit_val), val.y, n_cls),
        "heldout": classification_metrics(softmax(logit_val / temperature), val.y, n_cls),
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
        **(extra or {}),
    }
    return export_classifier(
        net,
        out_dir,
        fill=fill,
        nominal=nominal,
        window_s=config.window_s,
        temperature=temperature,
        unknown=unknown,
        coverage=coverage,
        coverage_entry=coverage_entry,
        calibration=calibration,
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
    coverage: Coverage,
    coverage_entry: dict[str, Any],
    calibration: dict[str, Any],
    hidden: tuple[int, ...],
    digest: str,
    metrics: dict[str, Any],
    extra: dict[str, Any],
) -> ClassifierCard:
    """Export ``net`` to ``out_dir`` (card, weights, program), atomically, and return the card
    (nothing is written when ``out_dir`` is None).

    Before the new folder replaces an old one, the compiled decision path (``mlp_forward``)
    must reproduce the program on probe features and the folder must load as a node loads it.

    Raises
    ------
    ModelMismatchError
        If the exported folder does not reproduce the network (nothing is replaced).
    FileExistsError
        If ``out_dir`` is an existing file.
    """
    net = net.eval()
    batch = torch.export.Dim("batch", min=1, max=1 << 20)
    example = torch.zeros(2, len(FEATURE_NAMES))
    program = torch.export.export(net, (example,), dynamic_shapes={"x": {0: batch}})
    arrays = state_arrays(program.state_dict)
    arrays[COVERAGE_ARRAY] = coverage.points * coverage.resolution
    h = hashlib.sha256()
    for name, arr in sorted(arrays.items()):
        h.update(name.encode())
        h.update(arr.tobytes())
    center = net.center.double().numpy()
    scale = net.scale.double().numpy()
    fields = dict(
        kind=KIND,
        model_id=f"classifier-mlp-{h.hexdigest()[:12]}",
        inputs=WINDOW_SIGNALS,
        outputs=CLASS_NAMES,
        class_names=CLASS_NAMES,
        scaling=scaling_entries(FEATURE_NAMES, center, scale),
        sample_time_s=nominal.sample_time_s,
        lookbacks={"window_samples": round(window_s / nominal.sample_time_s)},
        architecture="mlp",
        hidden=tuple(hidden),
        training_data_digest=digest,
        training_metrics=metrics,
        code_version=code_version(),
        created=datetime.now(UTC).isoformat(timespec="seconds"),
        features=FEATURE_NAMES,
        feature_fill={f: float(v) for f, v in zip(FEATURE_NAMES, fill, strict=True)},
        window_s=float(window_s),
        nominal_model_id=nominal.model_id,
        temperature=float(temperature),
        unknown=unknown,
        coverage=coverage_entry,
        calibration=calibration,
        extra=extra,
    )
    if out_dir is None:
        return ClassifierCard(**fields)
    with replaced_dir(out_dir) as stage:
        torch.export.save(program, stage / PROGRAM_FILE)
        (stage / WEIGHTS_FILE).write_bytes(weights_bytes(arrays))
        files = {name: file_sha256(stage / name) for name in (WEIGHTS_FILE, PROGRAM_FILE)}
        card = ClassifierCard(**fields, files=files)
        (stage / CARD_FILE).write_text(card.to_json())
        ClassifierModel.load(stage)
        check_program(program.module(), mlp_layers(arrays, stage / WEIGHTS_FILE), center, scale,
                      stage / PROGRAM_FILE)  # fmt: skip
    return card


def check_program(
    module: Any,
    layers: tuple[tuple[np.ndarray, np.ndarray], ...],
    center: np.ndarray,
    scale: np.ndarray,
    path: Path,
) -> None:
    """ModelMismatchError if ``mlp_forward`` (the runtime's compiled path) does not reproduce
    the program on probe features."""
    rng = np.random.default_rng(0)
    x = center + scale * rng.normal(scale=3.0, size=(16, len(center)))
    with torch.inference_mode():
        ref = module(torch.tensor(x, dtype=torch.float32)).double().numpy()
    fast = mlp_forward(layers, x, center, scale)
    err = float(np.max(np.abs(fast - ref)))
    if not err <= 1e-3 * max(1.0, float(np.max(np.abs(ref)))):
        raise ModelMismatchError(
            f"{path}: the program's graph differs from a ReLU MLP with these weights "
            f"(max logit difference {err:.3g})"
        )
