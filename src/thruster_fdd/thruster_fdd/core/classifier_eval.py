"""Evaluation of fault diagnosis: the paper's Table 3 protocol, per-window accuracy on unseen
thrusters, time from fault onset to a stable correct diagnosis, UNKNOWN on unlike inputs.

Table 3 protocol (simulated, ``Table3Config``): one ``t100`` unit (the paper's single thruster,
drawn by ``unit_seed``); per class ``train_samples`` samples of the 0.01 Hz sine at 10 Hz for
training and a separate recording (same unit, new noise) of ``test_samples`` for testing.
Classifiers: MLP on one sample, LSTM on the last ``lookback`` samples; inputs either the four
signals (command, voltage, rpm, current) or the two residuals of the exported nominal model
(computed by ``ResidualStream``, as online). 3-fold time-series cross-validation on the training
series (fold k trains on the first k quarters of every class's series, validates on quarter
k + 1), then a fit on all of it scored on the test set: per-sample accuracy and the normalised
confusion matrix. The paper: 78 % average accuracy for the MLP on residuals (best of six).

Beyond the paper (``WindowEvalConfig``): the exported window classifier through the online code
path (``diagnosis.trace_decisions``) on thrusters it never saw (unit seeds disjoint from
training), on several command profiles; balanced accuracy per window (an ``unknown`` answer
counts as wrong); fault injected mid-run for the onset-to-stable-diagnosis time.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from thruster_fdd.core.data import CLASS_NAMES, Trace
from thruster_fdd.core.diagnosis import (
    UNKNOWN,
    ClassifierModel,
    Decision,
    check_pair,
    trace_decisions,
)
from thruster_fdd.core.nominal import NominalModel
from thruster_fdd.core.physics import load_config, simulate
from thruster_fdd.core.residuals import ResidualStream
from thruster_fdd.core.scenario import run_scenario
from thruster_fdd.core.signals import make_signal
from thruster_fdd.core.simconfig import perturb_unit

PAPER_TABLE3_BEST = {"model": "MLP", "inputs": "residuals", "accuracy": 0.78}
"""The paper's best Table 3 result (DESIGN.md): MLP on residuals, 78 % average accuracy."""

TRAIN_UNIT_SEEDS: tuple[int, ...] = tuple(range(100, 108))
"""Unit seeds of the committed classifier's training traces (scripts/make_classifier_model.sh)."""

TRAIN_SIGNALS: dict[str, float] = {
    "sine:0.01": 300.0,
    "steps": 300.0,
    "multilevel": 300.0,
    "chirp": 300.0,
    "mission": 600.0,
}
"""Command profiles of the committed classifier's training traces and their lengths, s (the
mission profile, the hardest, gets twice the time)."""


MISSION_UNIT_SEEDS: tuple[int, ...] = tuple(range(108, 116))
"""Further units of the committed classifier's training data, mission profile only (more
low-excitation windows: idle, station keeping; raised mission accuracy on validation units)."""

MISSION_DURATION_S = 1200.0
"""Length of each ``MISSION_UNIT_SEEDS`` trace, s."""


def training_traces() -> list[tuple[str, Trace]]:
    """The committed classifier's training traces: ``(name, trace)`` for every class, unit of
    ``TRAIN_UNIT_SEEDS`` and profile of ``TRAIN_SIGNALS``, then every class and unit of
    ``MISSION_UNIT_SEEDS`` on the mission profile (t100, 10 Hz)."""
    jobs = [
        (seed, signal, duration)
        for seed in TRAIN_UNIT_SEEDS
        for signal, duration in TRAIN_SIGNALS.items()
    ] + [(seed, "mission", MISSION_DURATION_S) for seed in MISSION_UNIT_SEEDS]
    out = []
    for seed, signal, duration in jobs:
        for cond in CLASS_NAMES:
            tr = run_scenario(
                "t100", cond, signal=signal, duration_s=duration, seed=seed,
                thruster_id=f"u{seed}",
            )  # fmt: skip
            out.append((f"{cond}_{signal.replace(':', '')}_u{seed}", tr))
    return out


@dataclass(frozen=True)
class Table3Config:
    """The paper's Table 3 protocol on simulated data (module docstring)."""

    preset: str = "t100"
    rate_hz: float = 10.0
    sine_hz: float = 0.01
    train_samples: int = 2000
    test_samples: int = 2000
    unit_seed: int = 0
    test_noise_seed: int = 1
    folds: int = 3
    lookback: int = 20
    hidden: tuple[int, ...] = (64, 64)
    lstm_hidden: int = 32
    mlp_epochs: int = 300
    lstm_epochs: int = 25
    seed: int = 0


@dataclass(frozen=True)
class WindowEvalConfig:
    """Unseen-thruster evaluation of the exported classifier.

    Attributes
    ----------
    unit_seeds : tuple of int
        Units never used in training (disjoint from ``TRAIN_UNIT_SEEDS``).
    signals : tuple of str
        Command profiles of the constant-condition test traces.
    duration_s : float
        Length of each test trace, s.
    fault_signals : tuple of str
        Profiles of the fault-injection traces.
    fault_classes : tuple of str
        Conditions injected at ``fault_at_s`` into a ``nominal_15v`` start.
    fault_at_s, fault_duration_s : float
        Onset time and trace length, s.
    hop_s : float
        Decision period, s.
    hysteresis : int
        Consecutive agreeing windows for a label change.
    """

    unit_seeds: tuple[int, ...] = tuple(range(200, 206))
    signals: tuple[str, ...] = ("sine:0.01", "steps", "multilevel", "mission")
    duration_s: float = 300.0
    fault_signals: tuple[str, ...] = ("steps", "multilevel", "mission")
    fault_classes: tuple[str, ...] = ("broken_blade_1", "broken_blade_2", "biofouling")
    fault_at_s: float = 60.0
    fault_duration_s: float = 180.0
    hop_s: float = 1.0
    hysteresis: int = 2

    def with_seed(self, seed: int) -> WindowEvalConfig:
        """The same evaluation on other unseen units: seeds shifted by ``1000 * seed``."""
        if seed == 0:
            return self
        return WindowEvalConfig(
            **{**asdict(self), "unit_seeds": tuple(s + 1000 * seed for s in self.unit_seeds)}
        )


# ---------------------------------------------------------------------------------------------
# Metrics


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


# ---------------------------------------------------------------------------------------------
# Table 3: per-sample classifiers


@dataclass(frozen=True)
class SampleData:
    """Per-sample inputs of the Table 3 protocol.

    Attributes
    ----------
    signals : np.ndarray, shape (C, n, 4)
        Command, voltage (V), rpm, current (A) per class.
    residuals : np.ndarray, shape (C, n, 2)
        Residual rpm and current (A) per class.
    """

    signals: np.ndarray
    residuals: np.ndarray


def _residual_series(tr: Trace, nominal: NominalModel, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The first ``n`` valid samples of a trace: signals (n, 4) and residuals (n, 2)."""
    stream = ResidualStream(nominal)
    stream.reset()
    sig, res = [], []
    columns = (tr.t, tr.command, tr.voltage, tr.rpm, tr.current)
    for t, c, v, r, i in zip(*(a.tolist() for a in columns), strict=True):
        s = stream.push(t, c, v, r, i)
        if s is not None and s.valid:
            sig.append((c, v, r, i))
            res.append((s.residual_rpm, s.residual_current_a))
    if len(sig) < n:
        raise ValueError(f"trace gives {len(sig)} valid residual samples, need {n}")
    return np.asarray(sig[:n]), np.asarray(res[:n])


def table3_data(cfg: Table3Config, nominal: NominalModel) -> tuple[SampleData, SampleData]:
    """Train and test per-sample data: one unit, 0.01 Hz sine, test = same unit, new noise."""
    unit = perturb_unit(load_config(cfg.preset), cfg.unit_seed)
    margin = nominal.warmup_samples + 10
    out = []
    for n, noise in ((cfg.train_samples, cfg.unit_seed), (cfg.test_samples, cfg.test_noise_seed)):
        t, u = make_signal(f"sine:{cfg.sine_hz}", (n + margin) / cfg.rate_hz, cfg.rate_hz)
        sig, res = zip(
            *(
                _residual_series(simulate(unit, t, u, c, seed=noise), nominal, n)
                for c in CLASS_NAMES
            ),
            strict=True,
        )
        out.append(SampleData(np.stack(sig), np.stack(res)))
    return out[0], out[1]


class _LstmClassifier(nn.Module):
    def __init__(self, n_in: int, hidden: int, n_classes: int) -> None:
        super().__init__()
        self.rnn = nn.LSTM(n_in, hidden, batch_first=True)
        self.out = nn.Linear(hidden, n_classes)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, _ = self.rnn(x)
        return self.out(h[:, -1])


def _mlp(n_in: int, hidden: tuple[int, ...], n_classes: int) -> nn.Module:
    layers: list[nn.Module] = []
    for h in hidden:
        layers += [nn.Linear(n_in, h), nn.ReLU()]
        n_in = h
    return nn.Sequential(*layers, nn.Linear(n_in, n_classes))


def _sequences(x: np.ndarray, lookback: int) -> np.ndarray:
    """Sliding windows (C, n - lookback + 1, lookback, k) of per-class series (C, n, k)."""
    idx = np.arange(lookback - 1, x.shape[1])[:, None] - np.arange(lookback - 1, -1, -1)
    return x[:, idx]


def fit_predict_samples(
    kind: str, x_train: np.ndarray, x_test: np.ndarray, cfg: Table3Config
) -> np.ndarray:
    """Train a per-sample classifier and predict class indices for the test series.

    Parameters
    ----------
    kind : str
        ``"mlp"`` (one sample) or ``"lstm"`` (the last ``cfg.lookback`` samples).
    x_train : np.ndarray, shape (C, n_train, k)
        Training series per class.
    x_test : np.ndarray, shape (C, n_test, k)
        Test series per class.

    Returns
    -------
    np.ndarray, shape (C, m)
        Predicted class per test sample (``m = n_test`` for the MLP, ``n_test - lookback + 1``
        for the LSTM, whose first samples lack a full history).
    """
    torch.manual_seed(cfg.seed)
    flat = x_train.reshape(-1, x_train.shape[2])
    q25, med, q75 = np.percentile(flat, [25.0, 50.0, 75.0], axis=0)
    scale = np.maximum(q75 - q25, 1e-6 * np.maximum(np.abs(med), 1.0))
    n_cls = x_train.shape[0]
    ztr, zte = (x_train - med) / scale, (x_test - med) / scale
    if kind == "lstm":
        ztr, zte = _sequences(ztr, cfg.lookback), _sequences(zte, cfg.lookback)
        net: nn.Module = _LstmClassifier(x_train.shape[2], cfg.lstm_hidden, n_cls)
        epochs, batch = cfg.lstm_epochs, 256
    elif kind == "mlp":
        net = _mlp(x_train.shape[2], cfg.hidden, n_cls)
        epochs, batch = cfg.mlp_epochs, 0
    else:
        raise ValueError(f"unknown per-sample classifier {kind!r}; expected mlp or lstm")
    xt = torch.tensor(ztr.reshape(-1, *ztr.shape[2:]), dtype=torch.float32)
    yt = torch.tensor(np.repeat(np.arange(n_cls), ztr.shape[1]), dtype=torch.long)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3, weight_decay=1e-4)
    loss_fn = nn.CrossEntropyLoss()
    rng = np.random.default_rng(cfg.seed)
    for _ in range(epochs):
        batches = (
            [torch.arange(len(yt))]
            if batch == 0
            else torch.from_numpy(rng.permutation(len(yt))).split(batch)
        )
        for b in batches:
            opt.zero_grad()
            loss_fn(net(xt[b]), yt[b]).backward()
            opt.step()
    net.eval()
    with torch.inference_mode():
        xs = torch.tensor(zte.reshape(-1, *zte.shape[2:]), dtype=torch.float32)
        pred = net(xs).argmax(dim=1).numpy()
    return pred.reshape(n_cls, -1)


def run_table3(
    cfg: Table3Config, nominal: NominalModel, *, progress: bool = False
) -> list[dict[str, Any]]:
    """The four rows (MLP, LSTM) x (signals, residuals): CV accuracy, test accuracy, matrix.

    Returns
    -------
    list of dict
        ``{"model", "inputs", "cv_accuracy", "cv_folds", "test_accuracy",
        "confusion": (C, C) row-normalised list, "counts": (C, C) list}``.
    """
    train, test = table3_data(cfg, nominal)
    n = cfg.train_samples
    quarter = n // (cfg.folds + 1)
    rows = []
    jobs = [(m, i) for m in ("mlp", "lstm") for i in ("signals", "residuals")]
    for model, inputs in tqdm(jobs, desc="Table 3 per-sample", disable=not progress):
        xtr, xte = getattr(train, inputs), getattr(test, inputs)
        folds = []
        for k in range(1, cfg.folds + 1):
            val = xtr[:, k * quarter : (k + 1) * quarter]
            pred = fit_predict_samples(model, xtr[:, : k * quarter], val, cfg)
            folds.append(float(np.mean(pred == np.arange(len(CLASS_NAMES))[:, None])))
        pred = fit_predict_samples(model, xtr, xte, cfg)
        y_true = np.repeat(np.array(CLASS_NAMES, dtype=object), pred.shape[1])
        y_pred = np.array(CLASS_NAMES, dtype=object)[pred.reshape(-1)]
        counts = confusion(y_true, y_pred, CLASS_NAMES)[:, : len(CLASS_NAMES)]
        rows.append(
            {
                "model": model.upper(),
                "inputs": inputs,
                "cv_accuracy": float(np.mean(folds)),
                "cv_folds": folds,
                "test_accuracy": float(np.trace(counts) / counts.sum()),
                "confusion": normalise_rows(counts).tolist(),
                "counts": counts.tolist(),
            }
        )
    return rows


# ---------------------------------------------------------------------------------------------
# Beyond the paper: unseen thrusters, onset, UNKNOWN


def _labels(decisions: list[Decision], attr: str) -> np.ndarray:
    return np.array([getattr(d, attr) for d in decisions], dtype=object)


def window_accuracy(
    cfg: WindowEvalConfig,
    nominal: NominalModel,
    classifier: ClassifierModel,
    *,
    progress: bool = False,
) -> dict[str, Any]:
    """Per-window diagnosis of constant-condition traces of unseen units, per command profile.

    Returns
    -------
    dict
        ``{"per_signal": {signal: {"balanced_accuracy", "balanced_accuracy_stable",
        "unknown_rate", "windows"}}, "overall": {same}, "confusion": (C, C+1) row-normalised,
        "counts": (C, C+1)}``; ``balanced_accuracy`` scores each window's raw label,
        ``_stable`` the decision (label after evidence accumulation and hysteresis); unknown
        counts as wrong (last column).
    """
    jobs = [(s, u, c) for s in cfg.signals for u in cfg.unit_seeds for c in CLASS_NAMES]
    per: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {s: [] for s in cfg.signals}
    for signal, unit, cond in tqdm(jobs, desc="unseen thrusters", disable=not progress):
        tr = run_scenario(
            "t100", cond, signal=signal, duration_s=cfg.duration_s, seed=unit, thruster_id="eval"
        )
        ds = trace_decisions(tr, nominal, classifier, hop_s=cfg.hop_s, hysteresis=cfg.hysteresis)
        truth = np.full(len(ds), cond, dtype=object)
        per[signal].append((truth, _labels(ds, "raw_label"), _labels(ds, "label")))

    def summary(items: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> dict[str, Any]:
        truth = np.concatenate([a for a, _, _ in items])
        raw = np.concatenate([b for _, b, _ in items])
        stable = np.concatenate([c for _, _, c in items])
        counts = confusion(truth, raw, CLASS_NAMES)
        return {
            "balanced_accuracy": balanced_accuracy(counts),
            "balanced_accuracy_stable": balanced_accuracy(confusion(truth, stable, CLASS_NAMES)),
            "unknown_rate": float(np.mean(raw == UNKNOWN)),
            "windows": len(truth),
            "counts": counts.tolist(),
        }

    per_signal = {s: summary(items) for s, items in per.items()}
    overall = summary([x for items in per.values() for x in items])
    return {
        "per_signal": per_signal,
        "overall": overall,
        "confusion": normalise_rows(np.asarray(overall["counts"])).tolist(),
    }


def onset_latency(decisions: list[Decision], fault: str, fault_at_s: float) -> float:
    """Time from the fault onset to the first decision from which the label stays ``fault``
    to the end of the trace, s; ``inf`` when it never settles on it."""
    labels = _labels(decisions, "label")
    times = np.array([d.t_s for d in decisions])
    wrong = np.nonzero((labels != fault) | (times < fault_at_s))[0]
    first = 0 if len(wrong) == 0 else wrong[-1] + 1
    if first >= len(decisions):
        return float("inf")
    return float(max(times[first] - fault_at_s, 0.0))


def fault_onsets(
    cfg: WindowEvalConfig,
    nominal: NominalModel,
    classifier: ClassifierModel,
    *,
    progress: bool = False,
) -> dict[str, Any]:
    """Onset-to-stable-correct-diagnosis times of faults injected mid-run into unseen units.

    Returns
    -------
    dict
        ``{"median_s", "p95_s", "max_s", "runs", "never_settled", "per_fault": {fault:
        {"median_s", "p95_s"}}, "latencies_s": [...]}`` (runs that never settle count as inf
        in the percentiles).
    """
    jobs = [(s, u, f) for s in cfg.fault_signals for u in cfg.unit_seeds for f in cfg.fault_classes]
    lat: dict[str, list[float]] = {f: [] for f in cfg.fault_classes}
    for signal, unit, fault in tqdm(jobs, desc="fault onsets", disable=not progress):
        tr = run_scenario(
            "t100",
            "nominal_15v",
            signal=signal,
            duration_s=cfg.fault_duration_s,
            seed=unit,
            fault_at_s=cfg.fault_at_s,
            fault_condition=fault,
        )
        ds = trace_decisions(tr, nominal, classifier, hop_s=cfg.hop_s, hysteresis=cfg.hysteresis)
        lat[fault].append(onset_latency(ds, fault, cfg.fault_at_s))
    every = np.array([x for v in lat.values() for x in v])

    def pct(a: np.ndarray, q: float) -> float:
        return float(np.percentile(a, q, method="higher"))

    return {
        "median_s": pct(every, 50),
        "p95_s": pct(every, 95),
        "max_s": float(every.max()),
        "runs": len(every),
        "never_settled": int(np.sum(~np.isfinite(every))),
        "per_fault": {
            f: {"median_s": pct(np.array(v), 50), "p95_s": pct(np.array(v), 95)}
            for f, v in lat.items()
        },
        "latencies_s": every.tolist(),
    }


@dataclass(frozen=True)
class UnlikeCase:
    """An input unlike every class: a name and the ``run_scenario`` arguments that make it."""

    name: str
    preset: str
    condition: str
    voltage: float | None = None
    signal: str = "multilevel"
    kwargs: dict[str, Any] = field(default_factory=dict)


UNLIKE_CASES: tuple[UnlikeCase, ...] = (
    UnlikeCase("t200 thruster (other preset), nominal 15 V", "t200", "nominal_15v"),
    UnlikeCase(
        "t100 biofouling at 11.8 V (condition x voltage not a class)",
        "t100",
        "biofouling",
        voltage=11.8,
    ),
    UnlikeCase("t100 two broken blades at 13 V", "t100", "broken_blade_2", voltage=13.0),
    UnlikeCase("t100 nominal at 24 V (far out of range)", "t100", "nominal_15v", voltage=24.0),
)
"""Inputs the classifier should answer ``unknown``."""


def unknown_rates(
    nominal: NominalModel,
    classifier: ClassifierModel,
    *,
    unit_seeds: Sequence[int] = (300, 301),
    duration_s: float = 200.0,
) -> dict[str, dict[str, Any]]:
    """Share of windows answered ``unknown`` on each ``UNLIKE_CASES`` input.

    Returns
    -------
    dict
        ``{case name: {"unknown_rate", "unknown_rate_label", "windows", "most_common_class"}}``:
        share of windows whose own (raw) answer is unknown, and whose decision (label, after
        evidence accumulation and hysteresis) is.
    """
    out = {}
    for case in UNLIKE_CASES:
        raws, labels = [], []
        for unit in unit_seeds:
            tr = run_scenario(
                case.preset,
                case.condition,
                signal=case.signal,
                duration_s=duration_s,
                voltage=case.voltage,
                seed=unit,
            )
            ds = trace_decisions(tr, nominal, classifier)
            raws.append(_labels(ds, "raw_label"))
            labels.append(_labels(ds, "label"))
        raw = np.concatenate(raws)
        known = raw[raw != UNKNOWN]
        names, counts = np.unique(known, return_counts=True) if len(known) else ([], [])
        out[case.name] = {
            "unknown_rate": float(np.mean(raw == UNKNOWN)),
            "unknown_rate_label": float(np.mean(np.concatenate(labels) == UNKNOWN)),
            "windows": len(raw),
            "most_common_class": str(names[int(np.argmax(counts))]) if len(known) else None,
        }
    return out


# ---------------------------------------------------------------------------------------------
# Everything, as files


def run_evaluation(
    nominal_dir: str | Path,
    classifier_dir: str | Path,
    out_dir: str | Path,
    *,
    seed: int = 0,
    table3: Table3Config | None = None,
    windows: WindowEvalConfig | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Table 3 (paper protocol), unseen thrusters, fault onsets and UNKNOWN, written to
    ``out_dir`` as ``table3.md``, ``table3.json`` and confusion-matrix PNGs.

    ``seed`` seeds the per-sample classifiers and shifts the unseen units
    (``WindowEvalConfig.with_seed``).
    """
    table3 = table3 or Table3Config(seed=seed)
    windows = (windows or WindowEvalConfig()).with_seed(seed)
    overlap = set(windows.unit_seeds) & (set(TRAIN_UNIT_SEEDS) | set(MISSION_UNIT_SEEDS))
    if overlap:
        raise ValueError(f"evaluation units {sorted(overlap)} are training units")
    nominal = NominalModel.load(nominal_dir)
    classifier = ClassifierModel.load(classifier_dir)
    check_pair(nominal, classifier, classifier_dir)
    result: dict[str, Any] = {
        "paper": PAPER_TABLE3_BEST,
        "nominal_model_id": nominal.model_id,
        "classifier_model_id": classifier.model_id,
        "table3_config": asdict(table3),
        "window_config": asdict(windows),
    }
    result["per_sample"] = run_table3(table3, nominal, progress=progress)
    result["per_window"] = window_accuracy(windows, nominal, classifier, progress=progress)
    result["onset"] = fault_onsets(windows, nominal, classifier, progress=progress)
    result["unknown"] = unknown_rates(nominal, classifier)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table3.json").write_text(_json(result))
    (out / "table3.md").write_text(table3_markdown(result))
    plot_confusions(result, out)
    return result


def _json(obj: Any) -> str:
    import json

    def clean(x: Any) -> Any:
        if isinstance(x, float) and not np.isfinite(x):
            return str(x)
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, list | tuple):
            return [clean(v) for v in x]
        return x

    return json.dumps(clean(obj), indent=1) + "\n"


def table3_markdown(result: dict[str, Any]) -> str:
    """Markdown of the comparison: paper vs per-sample rows vs per-window on unseen units."""
    lines = [
        "| classifier | inputs | evaluation | 3-fold TS-CV acc. | test acc. |",
        "|---|---|---|---|---|",
        "| paper: MLP (best of six) | residuals | one T100, per sample | - | 0.780 |",
    ]
    for r in result["per_sample"]:
        lines.append(
            f"| ours: {r['model']} | {r['inputs']} | one unit, per sample | "
            f"{r['cv_accuracy']:.3f} | {r['test_accuracy']:.3f} |"
        )
    pw = result["per_window"]
    n_units = len(result["window_config"]["unit_seeds"])
    lines.append(
        f"| ours: window MLP (exported) | features of signals + residuals | {n_units} unseen "
        f"units, per window, balanced | - | {pw['overall']['balanced_accuracy']:.3f} |"
    )
    lines += ["", "Per-window balanced accuracy on unseen units, by command profile:", ""]
    lines += [
        "| profile | windows | balanced acc. (raw) | balanced acc. (decision) | unknown (raw) |",
        "|---|---|---|---|---|",
    ]
    for s, v in {**pw["per_signal"], "all": pw["overall"]}.items():
        lines.append(
            f"| {s} | {v['windows']} | {v['balanced_accuracy']:.4f} | "
            f"{v['balanced_accuracy_stable']:.4f} | {v['unknown_rate']:.3f} |"
        )
    on = result["onset"]
    lines += [
        "",
        f"Fault onset to stable correct diagnosis ({on['runs']} runs, "
        f"{on['never_settled']} never settled): median {on['median_s']:.1f} s, "
        f"p95 {on['p95_s']:.1f} s, max {on['max_s']:.1f} s.",
        "",
        "| fault | median s | p95 s |",
        "|---|---|---|",
    ]
    for f, v in on["per_fault"].items():
        lines.append(f"| {f} | {v['median_s']:.1f} | {v['p95_s']:.1f} |")
    lines += ["", "UNKNOWN on inputs unlike every class:", ""]
    lines += ["| input | windows | unknown (raw) | unknown (decision) |", "|---|---|---|---|"]
    for name, v in result["unknown"].items():
        lines.append(
            f"| {name} | {v['windows']} | {v['unknown_rate']:.3f} | {v['unknown_rate_label']:.3f} |"
        )
    return "\n".join(lines) + "\n"


_SHORT = ("15V", "13V", "11.8V", "1 blade", "2 blades", "fouled")


def plot_confusions(result: dict[str, Any], out_dir: Path) -> list[Path]:
    """``confusion_per_sample.png`` (the four Table 3 rows) and ``confusion_per_window.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    rows = result["per_sample"]
    fig, axes = plt.subplots(1, len(rows), figsize=(4.2 * len(rows), 4.2))
    for ax, r in zip(np.atleast_1d(axes), rows, strict=True):
        _matrix(ax, np.asarray(r["confusion"]), _SHORT, _SHORT)
        ax.set_title(f"{r['model']} on {r['inputs']}: {r['test_accuracy']:.3f}")
    fig.suptitle("Table 3 protocol, per sample (one unit, 0.01 Hz sine, test = new recording)")
    fig.tight_layout()
    paths.append(out_dir / "confusion_per_sample.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6.2, 5.2))
    m = np.asarray(result["per_window"]["confusion"])
    _matrix(ax, m, _SHORT, (*_SHORT, "unknown"))
    ba = result["per_window"]["overall"]["balanced_accuracy"]
    ax.set_title(f"window MLP, unseen units, all profiles: balanced {ba:.4f}")
    fig.tight_layout()
    paths.append(out_dir / "confusion_per_window.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def _matrix(ax: Any, m: np.ndarray, rows: Sequence[str], cols: Sequence[str]) -> None:
    ax.imshow(m, vmin=0, vmax=1, cmap="Blues")
    ax.set_xticks(range(len(cols)), cols, rotation=45, ha="right")
    ax.set_yticks(range(len(rows)), rows)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    for i in range(m.shape[0]):
        for j in range(m.shape[1]):
            if m[i, j] >= 0.005:
                color = "white" if m[i, j] > 0.6 else "black"
                ax.text(j, i, f"{m[i, j]:.2f}", ha="center", va="center", fontsize=8, color=color)
