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
from tqdm import tqdm

from thruster_fdd.core.atomic import replaced_file, write_text
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.diagnosis.stream import Decision
from thruster_fdd.core.labels import CLASS_NAMES, UNKNOWN
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.diagnosis.metrics import balanced_accuracy, confusion, normalise_rows
from thruster_fdd_shore.core.diagnosis.offline import check_pair, trace_decisions
from thruster_fdd_shore.core.diagnosis.table3 import (
    PAPER_TABLE3_BEST,
    Table3Config,
    run_table3,
    table3_markdown,
)
from thruster_fdd_shore.core.json_text import json_text
from thruster_fdd_shore.core.sim.scenario import run_scenario

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
    write_text(out / "table3.json", json_text(result, nonfinite=str, indent=1))
    write_text(out / "table3.md", table3_markdown(result))
    plot_confusions(result, out)
    return result


_SHORT = ("15V", "13V", "11.8V", "1 blade", "2 blades", "fouled")


def plot_confusions(result: dict[str, Any], out_dir: Path) -> list[Path]:
    """``confusion_per_sample.png`` (the four Table 3 rows) and ``confusion_per_window.png``,
    each naming the models it came from (``nominal_model_id``, ``classifier_model_id``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    rows = result["per_sample"]
    fig, axes = plt.subplots(1, len(rows), figsize=(4.2 * len(rows), 4.2))
    for ax, r in zip(np.atleast_1d(axes), rows, strict=True):
        _matrix(ax, np.asarray(r["confusion"]), _SHORT, _SHORT)
        ax.set_title(f"{r['model']} on {r['inputs']}: {r['test_accuracy']:.3f}")
    fig.suptitle(
        "Table 3 protocol, per sample (one unit, 0.01 Hz sine, test = new recording)\n"
        f"residuals of nominal model {result.get('nominal_model_id', '?')}",
        fontsize=10,
    )
    fig.tight_layout()
    paths.append(out_dir / "confusion_per_sample.png")
    with replaced_file(paths[-1]) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6.2, 5.2))
    m = np.asarray(result["per_window"]["confusion"])
    _matrix(ax, m, _SHORT, (*_SHORT, "unknown"))
    ba = result["per_window"]["overall"]["balanced_accuracy"]
    ax.set_title(
        f"window MLP, unseen units, all profiles: balanced {ba:.4f}\n"
        f"{result.get('classifier_model_id', '?')} on {result.get('nominal_model_id', '?')}",
        fontsize=9,
    )
    fig.tight_layout()
    paths.append(out_dir / "confusion_per_window.png")
    with replaced_file(paths[-1]) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
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
