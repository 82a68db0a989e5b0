"""Training of the nominal regressors: data, training loops, time-series CV, grid search.

Data: traces are resampled to the model's sample time (linear interpolation when a trace is not
uniformly sampled at that rate) and kept as separate sequences (no window crosses two traces).

Losses are mean squared errors in IQR-scaled units, both outputs weighted equally.
- Feed-forward (MLP, MLP-TDD) and series-parallel NARX: one-step-ahead error.
- Parallel NARX: one-step pretraining (which is the series-parallel model), then fine-tuning on the
  free-run (simulation) error over ``horizon`` samples from many starting points, each start
  initialised with measured outputs (multiple shooting, back-propagation through the unroll).
- LSTM / GRU: sequence error over chunks of ``chunk`` samples, the first ``burn_in`` excluded.
"""

from __future__ import annotations

import copy
import itertools
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from thruster_fdd.core.artifact import data_digest
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.nominal.card import NominalCard
from thruster_fdd.core.nominal.runtime import NarxWeights, narx_free_run
from thruster_fdd.core.nominal.spec import INPUTS, OUTPUTS, IqrScaler, ModelSpec
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.nominal.export import export_narx, state_arrays
from thruster_fdd_shore.core.nominal.networks import LagNet, RecurrentNet, build_network

DEFAULT_SAMPLE_TIME_S = 0.1
"""10 Hz: the ESC telemetry rate the nominal model runs at (and the Table 2 protocol)."""


DEFAULT_SPECS: dict[str, ModelSpec] = {
    "parallel": ModelSpec(
        "narx_deadband", hidden=(96,), input_lags=20, output_lags=2, feedback=("rpm",)
    ),
    "series-parallel": ModelSpec(
        "narx_deadband", hidden=(32,), input_lags=20, output_lags=3, feedback=("rpm", "current")
    ),
}
"""The exported NARX per mode (``grid_search`` and the Table 2 runs; docs/nominal_model.md).

Each mode has its own network: the series-parallel model feeds back both measured outputs (one
step ahead, the measured past current is the best predictor of the next current); the parallel
model feeds back only its own rpm, since a fed-back predicted current extrapolates worse from
the training signal in free run."""


DEFAULT_SPEC = DEFAULT_SPECS["parallel"]
"""The exported NARX of the default (parallel) mode."""


def default_spec(mode: str) -> ModelSpec:
    """The exported NARX hyperparameters for ``mode`` (``DEFAULT_SPECS``)."""
    if mode not in DEFAULT_SPECS:
        raise ValueError(f"unknown mode {mode!r}; expected one of {', '.join(DEFAULT_SPECS)}")
    return DEFAULT_SPECS[mode]


@dataclass(frozen=True)
class TrainConfig:
    """Training options.

    Attributes
    ----------
    mode : str
        ``"series-parallel"`` or ``"parallel"`` (NARX only; others ignore it).
    epochs : int
        Epochs of one-step (or sequence) training.
    finetune_epochs : int
        Epochs of free-run fine-tuning (parallel NARX).
    horizon : int
        Free-run unroll length in samples (parallel NARX).
    batch_size : int
        Mini-batch size of one-step training (free run uses ``4 * batch_size`` starts).
    lr : float
        Adam learning rate (fine-tuning uses a third of it).
    chunk, burn_in : int
        Sequence length and excluded state warm-up of LSTM / GRU training, samples.
    seed : int
        Seed of initialisation and shuffling.
    """

    mode: str = "parallel"
    epochs: int = 150
    finetune_epochs: int = 60
    horizon: int = 50
    batch_size: int = 64
    lr: float = 3e-3
    chunk: int = 300
    burn_in: int = 20
    seed: int = 0


DEFAULT_BATCH_SIZES: dict[str, int] = {"parallel": 64, "series-parallel": 32}
"""One-step mini-batch size per mode (``grid_search``; docs/nominal_model.md)."""


def default_config(mode: str = "parallel", **changes: Any) -> TrainConfig:
    """The training options of the exported NARX of ``mode`` (batch size per mode)."""
    default_spec(mode)
    return replace(TrainConfig(mode=mode, batch_size=DEFAULT_BATCH_SIZES[mode]), **changes)


@dataclass(frozen=True)
class Series:
    """One uniformly sampled sequence: inputs ``u`` (n, 2) (command, V), outputs ``y`` (n, 2)
    (rpm, A)."""

    u: np.ndarray
    y: np.ndarray


def resample(trace: Trace, sample_time_s: float) -> Series:
    """Trace -> uniformly sampled ``Series`` at ``sample_time_s`` (linear interpolation when
    the trace's own sample time differs by more than 1 % anywhere)."""
    t = trace.t
    cols = np.stack([trace.command, trace.voltage, trace.rpm, trace.current], axis=1)
    if len(t) > 1 and np.max(np.abs(np.diff(t) - sample_time_s)) > 0.01 * sample_time_s:
        grid = np.arange(t[0], t[-1] + 1e-9, sample_time_s)
        cols = np.stack([np.interp(grid, t, c) for c in cols.T], axis=1)
    if not np.all(np.isfinite(cols)):
        raise BadInputError("trace holds non-finite samples")
    return Series(cols[:, :2].copy(), cols[:, 2:].copy())


def prepare_series(traces: Sequence[Trace], sample_time_s: float) -> list[Series]:
    """Resample every trace; ValueError when there is nothing to train on."""
    if not traces:
        raise BadInputError("no traces given")
    return [resample(tr, sample_time_s) for tr in traces]


def fit_scalers(seqs: Sequence[Series]) -> tuple[IqrScaler, IqrScaler]:
    """IQR scalers of inputs and outputs over all sequences."""
    u = np.concatenate([s.u for s in seqs])
    y = np.concatenate([s.y for s in seqs])
    return IqrScaler.fit(INPUTS, u), IqrScaler.fit(OUTPUTS, y)


def series_digest(seqs: Sequence[Series]) -> str:
    """Training data digest over the resampled samples."""
    return data_digest([np.concatenate([s.u, s.y], axis=1) for s in seqs])


def lag_windows(
    seq: Series, input_lags: int, output_lags: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Regressor windows of one sequence.

    Returns
    -------
    u_hist : np.ndarray, shape (m, input_lags, 2)
        ``u[k - input_lags : k]`` for each target sample ``k`` (oldest first).
    y_hist : np.ndarray, shape (m, output_lags, 2)
        ``y[k - output_lags : k]``.
    target : np.ndarray, shape (m, 2)
        ``y[k]``, for ``k = max(lags) .. n - 1`` (``m = n - max(lags)``, may be 0).
    """
    w = max(input_lags, output_lags)
    idx = np.arange(w, len(seq.u))
    u_hist = seq.u[idx[:, None] - np.arange(input_lags, 0, -1)].reshape(len(idx), input_lags, 2)
    y_hist = seq.y[idx[:, None] - np.arange(output_lags, 0, -1)].reshape(len(idx), output_lags, 2)
    return u_hist, y_hist, seq.y[idx]


def _tensor(a: np.ndarray) -> torch.Tensor:
    return torch.tensor(a, dtype=torch.float32)


def train_model(
    spec: ModelSpec,
    seqs: Sequence[Series],
    config: TrainConfig,
    *,
    scalers: tuple[IqrScaler, IqrScaler] | None = None,
    progress: bool = False,
) -> tuple[nn.Module, nn.Module | None]:
    """Train one regressor on the given sequences.

    Parameters
    ----------
    spec : ModelSpec
    seqs : sequence of Series
        Training data at the model's sample time.
    config : TrainConfig
    scalers : (IqrScaler, IqrScaler) or None
        Input and output scalers; fitted on ``seqs`` when None.
    progress : bool
        Show tqdm progress bars.

    Returns
    -------
    (net, one_step_net)
        The trained network; for a parallel NARX also the one-step (series-parallel) network it
        was fine-tuned from, else None.
    """
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    u_scaler, y_scaler = scalers if scalers is not None else fit_scalers(seqs)
    net = build_network(spec, u_scaler, y_scaler)
    if isinstance(net, RecurrentNet):
        _train_recurrent(net, seqs, config, rng, progress)
        return net.eval(), None
    assert isinstance(net, LagNet)
    _train_one_step(net, seqs, config, rng, progress)
    if not (spec.is_narx and config.mode == "parallel" and config.finetune_epochs > 0):
        return net.eval(), None
    one_step = copy.deepcopy(net).eval()
    _train_free_run(net, seqs, config, rng, progress)
    return net.eval(), one_step


def _train_one_step(
    net: LagNet,
    seqs: Sequence[Series],
    config: TrainConfig,
    rng: np.random.Generator,
    progress: bool,
) -> None:
    spec = net.spec
    parts = [lag_windows(s, spec.input_lags, spec.output_lags) for s in seqs]
    u_h = _tensor(np.concatenate([p[0] for p in parts]))
    y_h = _tensor(np.concatenate([p[1] for p in parts]))
    target = _tensor(np.concatenate([p[2] for p in parts]))
    if len(target) == 0:
        raise BadInputError(f"traces are shorter than the lookback ({spec.warmup} samples)")
    opt = torch.optim.Adam(net.parameters(), lr=config.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(config.epochs, 1))
    y_scale = net.y_scale
    net.train()
    for _ in tqdm(range(config.epochs), desc=f"{spec.architecture} one-step", disable=not progress):
        order = torch.from_numpy(rng.permutation(len(target)))
        for batch in order.split(config.batch_size):
            pred = net(u_h[batch], y_h[batch])
            loss = (((pred - target[batch]) / y_scale) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()


def _train_free_run(
    net: LagNet,
    seqs: Sequence[Series],
    config: TrainConfig,
    rng: np.random.Generator,
    progress: bool,
) -> None:
    spec = net.spec
    nu, ny, h = spec.input_lags, spec.output_lags, config.horizon
    w = spec.warmup
    u_all, y_all, starts = [], [], []
    offset = 0
    for s in seqs:
        n = len(s.u)
        if n >= w + h:
            starts.append(offset + np.arange(w, n - h + 1))
        u_all.append(s.u)
        y_all.append(s.y)
        offset += n
    if not starts:
        raise BadInputError(f"traces are shorter than lookback + horizon ({w + h} samples)")
    start_idx = np.concatenate(starts)
    u = _tensor(np.concatenate(u_all))
    y = _tensor(np.concatenate(y_all))
    lag_u = torch.arange(nu, 0, -1)
    lag_y = torch.arange(ny, 0, -1)
    opt = torch.optim.Adam(net.parameters(), lr=config.lr / 3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(config.finetune_epochs, 1))
    y_scale = net.y_scale
    net.train()
    desc = f"{spec.architecture} free-run"
    for _ in tqdm(range(config.finetune_epochs), desc=desc, disable=not progress):
        order = torch.from_numpy(start_idx[rng.permutation(len(start_idx))])
        for batch in order.split(4 * config.batch_size):
            y_hist = y[batch[:, None] - lag_y]
            loss = torch.zeros(())
            for j in range(h):
                k = batch + j
                pred = net(u[k[:, None] - lag_u], y_hist)
                loss = loss + (((pred - y[k]) / y_scale) ** 2).mean()
                y_hist = torch.cat((y_hist[:, 1:], pred[:, None]), dim=1)
            opt.zero_grad()
            (loss / h).backward()
            nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
        sched.step()


def _train_recurrent(
    net: RecurrentNet,
    seqs: Sequence[Series],
    config: TrainConfig,
    rng: np.random.Generator,
    progress: bool,
) -> None:
    # Output t of the network predicts sample t + 1: inputs u[0 .. n-2], targets y[1 .. n-1].
    chunks_u, chunks_y = [], []
    for s in seqs:
        n = len(s.u) - 1
        length = min(config.chunk, n)
        if length <= config.burn_in:
            continue
        for a in range(0, n - length + 1, max(length // 4, 1)):
            chunks_u.append(s.u[a : a + length])
            chunks_y.append(s.y[a + 1 : a + 1 + length])
    if not chunks_u:
        raise BadInputError(f"traces are shorter than the burn-in ({config.burn_in} samples)")
    lengths = {len(c) for c in chunks_u}
    keep = min(lengths)
    u = _tensor(np.stack([c[:keep] for c in chunks_u]))
    y = _tensor(np.stack([c[:keep] for c in chunks_y]))
    opt = torch.optim.Adam(net.parameters(), lr=config.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(config.epochs, 1))
    net.train()
    desc = f"{net.spec.architecture} sequence"
    for _ in tqdm(range(config.epochs), desc=desc, disable=not progress):
        order = torch.from_numpy(rng.permutation(len(u)))
        for batch in order.split(max(config.batch_size // 8, 1)):
            pred = net(u[batch])
            err = ((pred - y[batch]) / net.y_scale)[:, config.burn_in :]
            loss = (err**2).mean()
            opt.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
        sched.step()


def predict_sequence(net: nn.Module, seq: Series, mode: str = "parallel") -> np.ndarray:
    """Predictions of a trained network over one sequence, shape (n, 2); NaN where undefined.

    Feed-forward models predict sample ``k`` from inputs before ``k`` (NaN for ``k <
    input_lags``); a NARX in ``"series-parallel"`` mode uses measured past outputs, in
    ``"parallel"`` mode its own (free run after ``warmup`` measured samples); LSTM / GRU run
    over the inputs from sample 0 (NaN at sample 0).
    """
    n = len(seq.u)
    out = np.full((n, 2), np.nan)
    if isinstance(net, RecurrentNet):
        with torch.inference_mode():
            out[1:] = net(_tensor(seq.u[None, :-1]))[0].double().numpy()
        return out
    assert isinstance(net, LagNet)
    spec = net.spec
    w = spec.warmup
    if n <= w:
        return out
    weights = NarxWeights.from_arrays(state_arrays(net), spec) if spec.is_narx else None
    if spec.is_narx and mode == "parallel" and weights is not None:
        out[w:] = narx_free_run(
            weights.predict, seq.u, seq.y[:w], spec.input_lags, spec.output_lags
        )
        return out
    u_h, y_h, _ = lag_windows(seq, spec.input_lags, spec.output_lags)
    with torch.inference_mode():
        out[w:] = net(_tensor(u_h), _tensor(y_h)).double().numpy()
    return out


def time_series_folds(n: int, n_folds: int, min_train: float = 0.5) -> list[tuple[int, int]]:
    """Expanding-window folds over ``n`` samples: validation always follows training in time.

    Returns
    -------
    list of (train_end, val_end)
        Fold ``i`` trains on ``[0, train_end)`` and validates on ``[train_end, val_end)``; the
        first ``min_train`` fraction is always training, the rest is cut into ``n_folds``
        consecutive validation blocks.
    """
    if n_folds < 1 or not 0 < min_train < 1:
        raise ValueError(f"need n_folds >= 1 and 0 < min_train < 1, got {n_folds}, {min_train}")
    first = int(n * min_train)
    edges = np.linspace(first, n, n_folds + 1).astype(int)
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]


def _cut(seqs: Sequence[Series], frac_a: float, frac_b: float) -> list[Series]:
    out = []
    for s in seqs:
        n = len(s.u)
        a, b = int(n * frac_a), int(n * frac_b)
        out.append(Series(s.u[a:b], s.y[a:b]))
    return out


def r2_score(y: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Coefficient of determination per column over rows where ``pred`` is finite; shape (k,)."""
    ok = np.all(np.isfinite(pred), axis=1)
    y, pred = y[ok], pred[ok]
    ss_res = np.sum((y - pred) ** 2, axis=0)
    ss_tot = np.sum((y - y.mean(axis=0)) ** 2, axis=0)
    return 1.0 - ss_res / np.where(ss_tot > 0, ss_tot, np.nan)


def rmse(y: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Root mean squared error per column over rows where ``pred`` is finite; shape (k,)."""
    ok = np.all(np.isfinite(pred), axis=1)
    return np.sqrt(np.mean((y[ok] - pred[ok]) ** 2, axis=0))


def cross_validate(
    spec: ModelSpec, seqs: Sequence[Series], config: TrainConfig, n_folds: int = 2
) -> float:
    """Mean validation r² (both outputs) over expanding-window folds, in ``config.mode``.

    Each fold trains on the first part of every sequence and validates, in the configuration of
    ``config.mode`` (free run for parallel), on the block that follows it; the free run of a
    validation block starts from that block's own first ``warmup`` measured samples.
    """
    scores = []
    n_min = min(len(s.u) for s in seqs)
    for train_end, val_end in time_series_folds(n_min, n_folds):
        fa, fb = train_end / n_min, val_end / n_min
        net, _ = train_model(spec, _cut(seqs, 0.0, fa), config)
        for val in _cut(seqs, fa, fb):
            pred = predict_sequence(net, val, config.mode)
            scores.append(float(np.nanmean(r2_score(val.y, pred))))
    return float(np.mean(scores))


@dataclass(frozen=True)
class GridResult:
    """One grid point: its spec, batch size, validation r² and training time (s)."""

    spec: ModelSpec
    batch_size: int
    score: float
    seconds: float


def grid_search(
    seqs: Sequence[Series],
    config: TrainConfig,
    *,
    architecture: str = "narx",
    hidden: Sequence[tuple[int, ...]] = ((32,), (64,)),
    batch_sizes: Sequence[int] = (32, 64),
    lookbacks: Sequence[tuple[int, int]] = ((10, 2), (20, 2), (20, 3)),
    n_folds: int = 2,
    feedback: tuple[str, ...] | None = None,
    progress: bool = False,
) -> list[GridResult]:
    """Grid search over hidden sizes, batch sizes and (input, output) lookbacks by time-series CV.

    ``feedback`` (NARX) defaults to that of ``DEFAULT_SPECS[config.mode]``; each point is scored
    by ``cross_validate`` in ``config.mode`` (free run for parallel).

    Returns
    -------
    list of GridResult
        Every grid point, best (highest validation r²) first.
    """
    results = []
    grid = list(itertools.product(hidden, batch_sizes, lookbacks))
    is_narx = architecture.startswith("narx")
    fb = feedback if feedback is not None else default_spec(config.mode).feedback
    for hid, bs, (nu, ny) in tqdm(grid, desc="grid search", disable=not progress):
        spec = ModelSpec(architecture, tuple(hid), nu, ny if is_narx else 0, fb)
        start = time.perf_counter()
        score = cross_validate(spec, seqs, replace(config, batch_size=bs), n_folds)
        results.append(GridResult(spec, bs, score, time.perf_counter() - start))
    return sorted(results, key=lambda r: -r.score)


def train_nominal(
    traces: Sequence[Trace],
    out_dir: str | Path,
    *,
    seed: int = 0,
    spec: ModelSpec | None = None,
    config: TrainConfig | None = None,
    sample_time_s: float = DEFAULT_SAMPLE_TIME_S,
    validation_fraction: float = 0.2,
    progress: bool = False,
    extra: dict[str, Any] | None = None,
) -> NominalCard:
    """Train the nominal NARX on nominal traces and export it to ``out_dir``.

    The last ``validation_fraction`` of every trace is held out (it follows the training part in
    time) for the card's validation metrics; then the model is retrained on all the data with
    the same seed and exported.

    Parameters
    ----------
    traces : sequence of Trace
        Nominal (healthy) traces.
    out_dir : str or Path
        Export directory.
    seed : int
        Seed of initialisation and shuffling: the same data and seed give the same weights.
    spec : ModelSpec or None
        NARX hyperparameters (default ``default_spec(config.mode)``).
    config : TrainConfig or None
        Training options (default ``default_config("parallel")``); ``config.mode`` is the mode
        the model is trained for and exported with.
    sample_time_s : float
        Model sample time, s.
    validation_fraction : float
        Held-out tail fraction for the card's validation metrics (0 to skip).
    progress : bool
        Show tqdm progress bars.
    extra : dict or None
        Further JSON-able facts for the card's ``extra`` (e.g. the training files' digests).

    Returns
    -------
    NominalCard
    """
    config = replace(config or default_config(), seed=seed)
    spec = spec if spec is not None else default_spec(config.mode)
    if not spec.is_narx:
        raise BadInputError(f"the nominal model is a NARX, got {spec.architecture}")
    seqs = prepare_series(traces, sample_time_s)
    metrics: dict[str, Any] = {}
    if validation_fraction > 0:
        train_part = _cut(seqs, 0.0, 1.0 - validation_fraction)
        val_part = _cut(seqs, 1.0 - validation_fraction, 1.0)
        net, _ = train_model(spec, train_part, config, progress=progress)
        metrics["validation"] = _metrics(net, val_part, config.mode)
        metrics["validation_fraction"] = validation_fraction
    net, _ = train_model(spec, seqs, config, progress=progress)
    metrics["train"] = _metrics(net, seqs, config.mode)
    assert isinstance(net, LagNet)
    extra = {
        "seed": seed,
        "train_config": {k: getattr(config, k) for k in config.__dataclass_fields__},
        "n_samples": int(sum(len(s.u) for s in seqs)),
        "n_traces": len(seqs),
        "init_window_s": spec.warmup * sample_time_s,
        **(extra or {}),
    }
    return export_narx(
        net,
        out_dir,
        mode=config.mode,
        sample_time_s=sample_time_s,
        training_data_digest=series_digest(seqs),
        training_metrics=metrics,
        extra=extra,
    )


def _metrics(net: nn.Module, seqs: Sequence[Series], mode: str) -> dict[str, float]:
    ys, ps = [], []
    for s in seqs:
        ys.append(s.y)
        ps.append(predict_sequence(net, s, mode))
    y, p = np.concatenate(ys), np.concatenate(ps)
    r2, err = r2_score(y, p), rmse(y, p)
    return {
        "mode": mode,
        "rpm_r2": float(r2[0]),
        "current_r2": float(r2[1]),
        "rpm_rmse": float(err[0]),
        "current_rmse": float(err[1]),
    }
