"""Offline diagnosis: a whole trace through the same code path as the nodes."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from thruster_fdd.core.artifact import CARD_FILE
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.diagnosis.stream import (
    EVIDENCE_TAU_S,
    FALSE_ALARMS_PER_HOUR,
    UNIT_ALLOWANCE,
    Decision,
    DiagnosisStream,
)
from thruster_fdd.core.errors import ModelMismatchError
from thruster_fdd.core.labels import FAULT_CLASSES, UNKNOWN
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
    false_alarms_per_hour: float = FALSE_ALARMS_PER_HOUR,
    unit_allowance: float = UNIT_ALLOWANCE,
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
        false_alarms_per_hour=false_alarms_per_hour,
        unit_allowance=unit_allowance,
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


def label_events(decisions: list[Decision]) -> list[dict[str, Any]]:
    """Each change of the published label (and the first one): ``{"t", "label",
    "confidence"}``, with the time (s) and confidence the node publishes with that decision."""
    events = []
    for i, d in enumerate(decisions):
        if i == 0 or d.label != decisions[i - 1].label:
            events.append({"t": d.t_s, "label": d.label, "confidence": d.confidence})
    return events


def first_fault(decisions: list[Decision]) -> dict[str, Any] | None:
    """The first published fault (``labels.FAULT_CLASSES``): ``{"label", "t", "onset_t"}``, or
    None.

    ``t`` is when it is published (the deciding window's end, s); ``onset_t`` estimates when
    the fault began: the middle of the first window of the run of windows, up to the published
    one, whose own answer (``raw_label``) is that fault, as a window turns once the fault fills
    about half of it (on 36 simulated onsets, seeds 700-711: median error -1.1 s, median
    absolute 3.1 s; docs/diagnosis.md has the numbers on fresh seeds).
    """
    for i, d in enumerate(decisions):
        if d.label not in FAULT_CLASSES:
            continue
        first = i
        while first > 0 and decisions[first - 1].raw_label == d.label:
            first -= 1
        w = decisions[first]
        return {"label": d.label, "t": d.t_s, "onset_t": 0.5 * (w.t_start_s + w.t_s)}
    return None


def overall_label(decisions: list[Decision]) -> dict[str, Any]:
    """The overall answer: the fault published longest when any fault was published (a fault
    anywhere is not averaged away), else the label published longest; its mean confidence."""
    if not decisions:
        return {"label": UNKNOWN, "confidence": 0.0}
    # Each decision stands until the next; the last one for a typical hop.
    hops = np.diff([d.t_s for d in decisions])
    durations = [*hops.tolist(), float(np.median(hops)) if len(hops) else 1.0]
    spans: dict[str, float] = {}  # insertion order: first published first, which wins ties
    for d, duration in zip(decisions, durations, strict=True):
        spans[d.label] = spans.get(d.label, 0.0) + duration
    pool = {k: v for k, v in spans.items() if k in FAULT_CLASSES} or spans
    label = max(pool, key=pool.__getitem__)
    confidence = float(np.mean([d.confidence for d in decisions if d.label == label]))
    return {"label": label, "confidence": confidence}


QUIET_TOLERANCE = 1e-3
"""Precision of ``quiet_allowance``, nats."""


def quiet_allowance(decisions: list[Decision]) -> float | None:
    """The smallest ``unit_allowance`` (nats per window length, to ``QUIET_TOLERANCE``) with
    which these decisions' sequential test never reaches its threshold; None without a window
    that gives evidence.

    The test publishes a fault when some run of informative windows adds up to
    ``sum(g * (r - k)) >= h`` (``Decision.evidence_weight`` g, ``Decision.fault_ratio`` r,
    allowance k, ``fault_threshold`` h), so the answer is the largest ``(sum(g r) - h) /
    sum(g)`` over all runs. It is found by bisection: a larger k only lowers the statistic.
    It does not depend on the allowance the decisions were made with. On healthy recordings
    of units the classifier was not trained on, the allowance must exceed the largest.
    """
    steps = [(d.evidence_weight, d.fault_ratio) for d in decisions if d.evidence_weight > 0.0]
    if not steps:
        return None
    threshold = next(d.fault_threshold for d in decisions if d.evidence_weight > 0.0)

    def publishes(k: float) -> bool:
        s = 0.0
        for g, r in steps:
            s = max(s + g * (r - k), 0.0)
            if s >= threshold:
                return True
        return False

    lo = max(r - threshold / g for g, r in steps) - 1.0  # one window alone passes it
    hi = max(r for _, r in steps)  # no window adds evidence
    while hi - lo > QUIET_TOLERANCE:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if publishes(mid) else (lo, mid)
    return hi


def summarize_decisions(decisions: list[Decision]) -> dict:
    """The ``diagnose`` JSON (docs/contracts.md) from decisions: ``overall``
    (``overall_label``), ``events`` (``label_events``), ``first_fault`` (``first_fault``),
    ``quiet_allowance`` (``quiet_allowance``) and ``windows``."""
    windows = [
        {
            "t_start": d.t_start_s,
            "t_end": d.t_s,
            "label": d.label,
            "raw_label": d.raw_label,
            "confidence": d.confidence,
            "probabilities": d.probabilities,
            "reason": d.reason,
            "covered": d.covered,
            "fault_evidence": d.fault_evidence,
            "fault_candidate": d.fault_candidate,
        }
        for d in decisions
    ]
    reasons: dict[str, int] = {}
    for d in decisions:
        if d.reason:
            reasons[d.reason] = reasons.get(d.reason, 0) + 1
    return {
        "overall": overall_label(decisions),
        "events": label_events(decisions),
        "first_fault": first_fault(decisions),
        "unknown_reasons": reasons,
        "fault_threshold": decisions[0].fault_threshold if decisions else None,
        "quiet_allowance": quiet_allowance(decisions),
        "windows": windows,
    }


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
        ``{"start", "overall": {"label", "confidence"}, "events": [{"t", "label",
        "confidence"}], "first_fault": {"label", "t", "onset_t"} or None, "windows":
        [{"t_start", "t_end", "label", "raw_label", "confidence", "probabilities": {class:
        p}, "reason", "covered", "fault_evidence", "fault_candidate"}], "unknown_reasons":
        {reason: windows}, "fault_threshold"}`` (docs/contracts.md keys; times in s on the
        trace's clock, ``start`` its first sample).

    Raises
    ------
    ValueError
        If a model does not load or the two do not belong together.
    """
    nominal = NominalModel.load(nominal_dir)
    classifier = ClassifierModel.load(classifier_dir)
    check_pair(nominal, classifier, classifier_dir)
    decisions = trace_decisions(trace, nominal, classifier, hop_s=hop_s)
    return {"start": float(trace.t[0]) if len(trace) else 0.0} | summarize_decisions(decisions)
