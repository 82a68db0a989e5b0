"""Offline diagnosis: a whole trace through the same code path as the nodes."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from thruster_fdd.core.artifact import CARD_FILE
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.diagnosis.stream import EVIDENCE_TAU_S, Decision, DiagnosisStream
from thruster_fdd.core.errors import ModelMismatchError
from thruster_fdd.core.labels import UNKNOWN
from thruster_fdd.core.nominal.residuals import ResidualStream
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd.core.traces.data import Trace


def check_pair(nominal: NominalModel, classifier: ClassifierModel, classifier_dir: Any) -> None:
    """ValueError if the classifier was not made with this nominal model's residuals."""
    if classifier.nominal_model_id != nominal.model_id:
        raise ModelMismatchError(
            f"{Path(classifier_dir) / CARD_FILE}: made with nominal model "
            f"{classifier.nominal_model_id!r}, but the nominal model is {nominal.model_id!r}"
        )
    if not math.isclose(classifier.sample_time_s, nominal.sample_time_s, rel_tol=1e-6):
        raise ModelMismatchError(
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
    """The ``diagnose`` JSON (docs/contracts.md) from decisions.

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
        "raw_label", "confidence", "probabilities": {class: p}}]}`` (docs/contracts.md keys,
        times in s).

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
