"""The decision layer without a trained network: coverage and excitation gates, the sequential
fault test and its threshold, clipped probabilities, the health tracker's last trustworthy label.

A classifier of fixed window probabilities stands in for the network, so each property can be
checked for every sequence of window probabilities (hypothesis), not only for those a trained
model happens to give.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from thruster_fdd.core.diagnosis.coverage import OPERATING_POINT, RESOLUTION, Coverage
from thruster_fdd.core.diagnosis.health import HealthTracker
from thruster_fdd.core.diagnosis.model import P_MIN, bounded
from thruster_fdd.core.diagnosis.reference import ThrustReference
from thruster_fdd.core.diagnosis.stream import (
    LLR_CLIP,
    LOW_EXCITATION,
    OUTSIDE_TRAINING,
    UNIT_ALLOWANCE,
    DiagnosisStream,
    fault_threshold,
)
from thruster_fdd.core.labels import CLASS_NAMES, FAULT_CLASSES, UNKNOWN

DRIVEN = (0.6, 15.0, 2600.0, 3.0, 0.0, 0.0)
IDLE = (0.0, 15.0, 0.0, 0.05, 0.0, 0.0)
RES = np.array([RESOLUTION[n] for n in OPERATING_POINT])


class FixedProbabilities:
    """The part of ``ClassifierModel`` the stream uses, answering each window with the next
    row of ``rows`` (C,) and covering the operating points near ``covered_points`` (N, 4)."""

    class_names = CLASS_NAMES
    sample_time_s = 0.1
    window_samples = 20
    window_s = 2.0
    probability_threshold = 0.5
    distance_threshold = 10.0

    def __init__(
        self, rows: Iterator[np.ndarray], covered_points: np.ndarray, min_command_abs: float = 0.0
    ) -> None:
        self._rows = rows
        self.min_command_abs = min_command_abs
        self.coverage = Coverage(
            points=np.repeat(covered_points, 5, axis=0) / RES, resolution=RES, threshold=1.0
        )

    def predict_proba(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = np.asarray(next(self._rows), dtype=float)
        return bounded(p[None] / p.sum()), np.zeros(1)


def _probs(fault: str | None, strength: float) -> np.ndarray:
    """Window probabilities: ``strength`` on ``fault`` (or on nominal_15v), the rest spread."""
    k = CLASS_NAMES.index(fault or "nominal_15v")
    p = np.full(len(CLASS_NAMES), (1.0 - strength) / (len(CLASS_NAMES) - 1))
    p[k] = strength
    return p


def _run(
    rows: list[np.ndarray],
    samples: list[tuple],
    covered: np.ndarray,
    min_command_abs: float = 0.0,
    **kw: float,
) -> list:
    model = FixedProbabilities(iter(rows), covered, min_command_abs)
    stream = DiagnosisStream(model, hop_s=0.1, **kw)  # type: ignore[arg-type]
    out = [stream.push(0.1 * k, *row, True) for k, row in enumerate(samples)]
    return [d for d in out if d is not None]


DRIVEN_POINT = np.array([[0.6, 0.6, 0.0, 15.0]])


def test_threshold_follows_the_false_alarm_rate() -> None:
    assert fault_threshold(1e-3, 20.0) == pytest.approx(math.log(3600 / 20 / 1e-3))
    assert fault_threshold(1e-4, 20.0) > fault_threshold(1e-3, 20.0)
    for bad in (0.0, -1.0, math.nan, 3600.0 / 20.0):
        with pytest.raises(ValueError, match="false_alarms_per_hour"):
            fault_threshold(bad, 20.0)


@given(strength=st.floats(0.9, 1.0 - 1e-6), fault=st.sampled_from(FAULT_CLASSES))
@settings(max_examples=25, deadline=None)
def test_a_steady_fault_is_published_once_its_evidence_reaches_the_threshold(
    strength: float, fault: str
) -> None:
    n = 600
    decisions = _run([_probs(fault, strength)] * n, [DRIVEN] * (n + 19), DRIVEN_POINT)
    h = decisions[0].fault_threshold
    p = bounded(_probs(fault, strength)[None])[0]
    faults = np.array([c in FAULT_CLASSES for c in CLASS_NAMES])
    llr = math.log(p[faults].sum() / p[~faults].sum())  # equal priors: 3 healthy, 3 faults
    step = 0.1 / 2.0 * (min(llr, LLR_CLIP) - UNIT_ALLOWANCE)
    first = next(i for i, d in enumerate(decisions) if d.label == fault)
    assert first == math.ceil(h / step - 1e-9) - 1
    assert all(d.label != fault for d in decisions[:first])
    assert all(d.label in (UNKNOWN, fault) or d.label not in FAULT_CLASSES for d in decisions)


@given(
    rows=st.lists(
        st.tuples(st.sampled_from(FAULT_CLASSES), st.floats(0.0, 0.45)), min_size=50, max_size=50
    )
)
@settings(max_examples=25, deadline=None)
def test_windows_that_favour_health_never_publish_a_fault(rows: list) -> None:
    # Each window gives the faults at most 0.15 together and health the rest: the likelihood
    # ratio of a fault against health stays below 1, so evidence never grows.
    probs = []
    for fault, share in rows:
        p = _probs(None, 0.0)
        p[:] = 0.0
        p[CLASS_NAMES.index(fault)] = share / 3.0
        p[[CLASS_NAMES.index(c) for c in CLASS_NAMES if c not in FAULT_CLASSES]] = (
            1.0 - share / 3.0
        ) / 3.0
        probs.append(p)
    decisions = _run(probs * 10, [DRIVEN] * (500 + 19), DRIVEN_POINT)
    assert not any(d.label in FAULT_CLASSES for d in decisions)
    assert all(d.fault_evidence == 0.0 for d in decisions)


def _ratio_probs(llr: float, fault: str) -> np.ndarray:
    """Window probabilities whose fault log-likelihood ratio is ``llr``, all on ``fault``."""
    p_fault = 1.0 / (1.0 + math.exp(-llr))
    p = np.zeros(len(CLASS_NAMES))
    p[CLASS_NAMES.index(fault)] = p_fault
    p[[CLASS_NAMES.index(c) for c in CLASS_NAMES if c not in FAULT_CLASSES]] = (1 - p_fault) / 3
    return p


@given(
    share=st.floats(0.2, 0.95),
    fault=st.sampled_from(FAULT_CLASSES),
    allowance=st.floats(1.0, 4.0),
)
@settings(max_examples=10, deadline=None)
def test_a_unit_offset_within_the_allowance_never_adds_up_to_a_fault(
    share: float, fault: str, allowance: float
) -> None:
    # Every window of a healthy unit whose spread looks a little like a fault gives the same
    # positive ratio: below the allowance it publishes no fault and gathers no evidence over
    # windows worth three thresholds without the allowance, where the same windows do.
    llr = share * allowance
    rows = [_ratio_probs(llr, fault)] * math.ceil(3 * fault_threshold(1e-3, 2.0) / (0.05 * llr))
    samples = [DRIVEN] * (len(rows) + 19)
    within = _run(rows, samples, DRIVEN_POINT, unit_allowance=allowance)
    assert not any(d.label in FAULT_CLASSES or d.fault_evidence > 0.0 for d in within)
    without = _run(rows, samples, DRIVEN_POINT, unit_allowance=0.0)
    assert any(d.label == fault for d in without)


def test_the_allowance_is_checked() -> None:
    model = FixedProbabilities(iter([]), DRIVEN_POINT)
    for bad in (-0.1, math.nan, LLR_CLIP + 1.0):
        with pytest.raises(ValueError, match="unit_allowance"):
            DiagnosisStream(model, unit_allowance=bad)  # type: ignore[arg-type]


def test_uncovered_and_idle_windows_are_unknown_and_change_no_evidence() -> None:
    n = 100
    rows = [_probs("broken_blade_2", 0.99)] * (3 * n)
    elsewhere = np.array([[0.2, 0.2, 0.0, 15.0]])  # covers 0.2, not the driven 0.6
    outside = _run(rows, [DRIVEN] * (n + 19), elsewhere)
    assert all(d.label == UNKNOWN and d.reason == OUTSIDE_TRAINING for d in outside)
    assert all(d.fault_evidence == 0.0 and not d.covered for d in outside)
    assert all(d.evidence_weight == 0.0 for d in outside)
    idle = _run(rows, [DRIVEN] * (n + 19) + [IDLE] * 60, DRIVEN_POINT)
    quiet = [d for d in idle[n:] if d.reason == LOW_EXCITATION]
    assert quiet
    assert all(d.label == UNKNOWN for d in quiet)
    assert len({d.fault_evidence for d in quiet}) == 1  # frozen while the rotor stands
    assert all(d.evidence_weight == 0.0 for d in quiet)
    assert all(d.evidence_weight == pytest.approx(0.1 / 2.0) for d in idle[:n])


@given(floor=st.floats(0.0, 1.0), command=st.floats(0.05, 1.0))
@settings(max_examples=30, deadline=None)
def test_windows_below_the_evidence_floor_give_no_evidence(floor: float, command: float) -> None:
    assume(abs(command - floor) > 1e-9)  # a window's mean of equal commands may be an ulp off
    n = 60
    rows = [_probs("broken_blade_2", 0.99)] * (n + 1)
    point = np.array([[command, command, 0.0, 15.0]])
    driven = (command, 15.0, 2600.0, 3.0, 0.0, 0.0)
    decisions = _run(rows, [driven] * (n + 19), point, floor)
    if command < floor:
        assert all(d.label == UNKNOWN and d.reason == LOW_EXCITATION for d in decisions)
        assert all(d.fault_evidence == 0.0 and d.evidence_weight == 0.0 for d in decisions)
    else:
        assert all(d.evidence_weight > 0.0 for d in decisions)
        assert decisions[-1].fault_evidence > 0.0
    never = _run(rows, [driven] * (n + 19), point, math.inf)
    assert all(d.reason == LOW_EXCITATION and d.fault_evidence == 0.0 for d in never)


def test_published_probabilities_are_bounded() -> None:
    rows = [np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])] * 40
    for d in _run(rows, [DRIVEN] * 59, DRIVEN_POINT):
        assert all(P_MIN <= v <= 1.0 - P_MIN for v in d.probabilities.values())
        assert P_MIN <= d.confidence <= 1.0 - P_MIN


def test_a_fault_clears_only_after_as_much_evidence_of_health() -> None:
    fault = [_probs("biofouling", 0.99)] * 400
    health = [_probs(None, 0.99)] * 800
    decisions = _run(fault + health, [DRIVEN] * 1219, DRIVEN_POINT)
    labels = [d.label for d in decisions]
    first = labels.index("biofouling")
    cleared = next(i for i in range(first, len(labels)) if labels[i] not in FAULT_CLASSES)
    assert cleared > 400  # the fault stands into the healthy windows
    assert labels[-1] == "nominal_15v"


def _reference() -> ThrustReference:
    from thruster_fdd.core.artifact import default_models_dir

    return ThrustReference.load(default_models_dir() / "reference")


def test_health_keeps_the_last_trustworthy_label_and_says_how_old_it_is() -> None:
    tracker = HealthTracker(["a"], _reference(), stale_after_s=3.0)
    tracker.add_diagnosis("a", "broken_blade_1", 0.9, 0.0)
    tracker.add_diagnosis("a", UNKNOWN, 0.3, 2.0, OUTSIDE_TRAINING)
    (e,) = tracker.snapshot(2.5)
    assert (e.label, e.faulty, e.unknown_reason) == ("broken_blade_1", True, OUTSIDE_TRAINING)
    assert e.label_age_s == pytest.approx(2.5)
    tracker.add_diagnosis("a", UNKNOWN, 0.3, 3.0, "unlike_classes")
    (e,) = tracker.snapshot(3.0)
    assert (e.label, e.faulty) == (UNKNOWN, False)
    (e,) = tracker.snapshot(10.0)
    assert e.stale
    assert e.label == UNKNOWN
