"""Online diagnosis of one thruster: residual samples in, a ``Decision`` every hop.

Pipeline (the same online in the classifier node and offline in ``diagnosis.offline``)::

    telemetry --ResidualStream(nominal model)--> residual samples at the model's sample time
      --WindowFeaturizer--> one feature vector (diagnosis.features) per hop over the last window_s
      --ClassifierModel--> calibrated class probabilities + distance to the nearest class
      --DiagnosisStream--> coverage and excitation gate -> evidence (healthy classes: weighted
        mean of log-probabilities and hysteresis; faults: a sequential test on log-likelihood
        ratios beyond what a healthy unit shows) -> Decision
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from thruster_fdd.core.diagnosis.coverage import OPERATING_POINT, operating_point
from thruster_fdd.core.diagnosis.features import FEATURE_NAMES, WINDOW_SIGNALS, window_features
from thruster_fdd.core.diagnosis.model import P_MIN, ClassifierModel
from thruster_fdd.core.labels import FAULT_CLASSES, UNKNOWN

MAX_GAP_PERIODS = 3.0
"""A step longer than this many sample times between valid samples restarts the window."""


EVIDENCE_TAU_S = 5.0
"""Time constant of the decision layer's evidence accumulation, s of *excited* operation: each
window's log-probabilities enter an exponentially weighted mean that forgets at this rate only
while the thruster turns (tuned on validation units 400-405, docs/diagnosis.md)."""


FALSE_ALARMS_PER_HOUR = 1e-3
"""Default false-alarm rate the fault threshold is set for, per hour of covered operation."""

UNIT_ALLOWANCE = 1.5
"""Allowance of the test against healthy thrusters, nats per window length: only the part of a
window's log-likelihood ratio above it counts as evidence. The windows of one thruster share its
manufacturing offsets, so they are not independent given its condition: a healthy unit whose
gains sit where a fault puts them has a positive mean ratio at every window, and without an
allowance its evidence would grow without bound. A recording stays free of faults when the
allowance exceeds its quiet allowance (``offline.quiet_allowance`` ashore, docs/diagnosis.md)."""

LLR_CLIP = math.log((1.0 - P_MIN) / P_MIN)
"""Largest log-likelihood ratio one window can contribute (the probabilities' own bound)."""

OUTSIDE_TRAINING = "outside_training"
LOW_EXCITATION = "low_excitation"
UNLIKE_CLASSES = "unlike_classes"
EVIDENCE_PENDING = "evidence_pending"
WARMING_UP = "warming_up"
REASONS: tuple[str, ...] = (
    OUTSIDE_TRAINING,
    LOW_EXCITATION,
    UNLIKE_CLASSES,
    EVIDENCE_PENDING,
    WARMING_UP,
)
"""Why a decision is ``"unknown"`` (``Decision.reason``; ``Diagnosis.reason``):
``outside_training``: the window's operating point is outside the classifier's training region;
``low_excitation``: the rotor hardly turned, or its mean |command| is below the classifier's
evidence floor (``ClassifierModel.min_command_abs``: where held-out units were not told healthy
from faulty reliably); ``unlike_classes``: the features are unlike every
class; ``evidence_pending``: the evidence leans to a fault that the sequential test has not yet
confirmed; ``warming_up``: no informative window yet."""


def fault_threshold(false_alarms_per_hour: float, window_s: float) -> float:
    """Evidence (nats) at which the sequential test publishes a fault, for a false-alarm rate.

    The test's statistic is a CUSUM of calibrated log-likelihood ratios, each overlapping
    window weighted by hop / window so that one window length of data counts once. For such a
    test the mean time between false alarms is at least ``exp(h)`` independent steps (Lorden's
    bound); with one step per window length, ``h = ln(3600 / (rate * window_s))``.

    Raises
    ------
    ValueError
        If the rate is not in (0, 3600 / window_s) per hour or the window is not > 0.
    """
    if not (math.isfinite(window_s) and window_s > 0):
        raise ValueError(f"window_s must be > 0, got {window_s}")
    limit = 3600.0 / window_s
    if not (math.isfinite(false_alarms_per_hour) and 0 < false_alarms_per_hour < limit):
        raise ValueError(
            f"false_alarms_per_hour must be in (0, {limit:g}), got {false_alarms_per_hour}"
        )
    return math.log(limit / false_alarms_per_hour)


def fault_log_ratio(fault_p: float, healthy_classes: int, fault_classes: int) -> float:
    """Log-likelihood ratio (nats) of "some fault" against "healthy" for a window whose fault
    classes together have probability ``fault_p`` (0..1, exclusive), with equal class priors
    over ``healthy_classes`` and ``fault_classes``; clipped to ``LLR_CLIP``. This is what the
    sequential test adds, before the allowance."""
    llr = math.log(fault_p) - math.log(1.0 - fault_p) + math.log(healthy_classes / fault_classes)
    return min(max(llr, -LLR_CLIP), LLR_CLIP)


EXCITATION_RANGE: tuple[float, float] = (0.3, 0.6)
"""Share of turning samples (feature ``active_fraction``) over which a window's evidence weight
ramps from 0 to 1: a window that mostly idles gives no evidence, so the label does not flip on
it (idle and station keeping confuse nominal and one broken blade)."""


class WindowFeaturizer:
    """Collects valid residual samples into a sliding window; features every hop.

    Parameters
    ----------
    window_samples : int
        Samples per window (>= 4).
    hop_samples : int
        Samples between two feature vectors once the window is full (>= 1).
    sample_time_s : float
        Expected time between samples, s; a step longer than ``MAX_GAP_PERIODS`` of it, or
        time going back, restarts the window.
    """

    def __init__(self, window_samples: int, hop_samples: int, sample_time_s: float) -> None:
        if window_samples < 4 or hop_samples < 1 or not sample_time_s > 0:
            raise ValueError(
                f"need window_samples >= 4, hop_samples >= 1, sample_time_s > 0; got "
                f"{window_samples}, {hop_samples}, {sample_time_s}"
            )
        self.window_samples = window_samples
        self.hop_samples = hop_samples
        self.sample_time_s = sample_time_s
        # Rows (t, *values) in a ring twice the window long: the window is always the contiguous
        # slice ending at ``_end``; when the ring is full its last rows move to the front.
        self._ring = np.empty((2 * window_samples, 1 + len(WINDOW_SIGNALS)))
        self._end = 0
        self._count = 0
        self._since = 0
        self._fresh = True
        self._last_t: float | None = None

    def reset(self) -> None:
        """Empty the window."""
        self._end = 0
        self._count = 0
        self._since = 0
        self._fresh = True
        self._last_t = None

    def push(
        self, t_s: float, values: tuple[float, float, float, float, float, float], valid: bool
    ) -> tuple[float, float, np.ndarray, np.ndarray] | None:
        """Add one sample; every hop with a full window return its times, features and
        operating point.

        Parameters
        ----------
        t_s : float
            Sample time, s.
        values : tuple of 6 float
            ``WINDOW_SIGNALS``: command, voltage (V), rpm, current (A), residual rpm, residual
            current (A).
        valid : bool
            False (or a non-finite value) skips the sample.

        Returns
        -------
        (t_start, t_end, features, operating_point) or None
            Times of the window's first and last sample (s), ``window_features`` (F,) and
            ``coverage.operating_point`` (4,).
        """
        if not valid or not (math.isfinite(t_s) and all(math.isfinite(v) for v in values)):
            return None
        if self._last_t is not None:
            dt = t_s - self._last_t
            if dt <= 0 or dt > MAX_GAP_PERIODS * self.sample_time_s:
                self.reset()
        self._last_t = t_s
        if self._end == len(self._ring):
            keep = self.window_samples - 1
            self._ring[:keep] = self._ring[self._end - keep : self._end]
            self._end = keep
        self._ring[self._end, 0] = t_s
        self._ring[self._end, 1:] = values
        self._end += 1
        self._count = min(self._count + 1, self.window_samples)
        self._since += 1
        if self._count < self.window_samples:
            return None
        if not (self._fresh or self._since >= self.hop_samples):
            return None
        self._fresh = False
        self._since = 0
        arr = self._ring[self._end - self._count : self._end]
        samples = arr[:, 1:]
        return (
            float(arr[0, 0]),
            float(arr[-1, 0]),
            window_features(samples, self.sample_time_s),
            operating_point(samples),
        )


@dataclass(frozen=True)
class Decision:
    """One diagnosis of one thruster over the last window.

    Attributes
    ----------
    t_s : float
        Time of the window's last sample, s.
    label : str
        Condition after hysteresis: a class name or ``"unknown"``.
    raw_label : str
        This window's own answer: the most probable class, or ``"unknown"`` when the top
        probability is under the threshold or the features are unlike every class.
    probabilities : dict of str to float
        Calibrated class probabilities (sum 1).
    confidence : float
        Probability of the most probable class.
    window_s : float
        Window length, s.
    t_start_s : float
        Time of the window's first sample, s.
    distance : float
        Distance of the window's features to the nearest class (standardised RMS).
    reason : str
        Why ``label`` is ``"unknown"`` (one of ``REASONS``), ``""`` when it is a class.
    covered : bool
        The window's operating point lies in the classifier's training region.
    coverage_distance : float
        Its distance to the training region (``coverage.Coverage.distance``).
    fault_evidence : float
        The sequential test's statistic, nats (0 with no evidence of a fault).
    fault_candidate : str
        The fault class with the most accumulated evidence, ``""`` while ``fault_evidence`` is
        0.
    fault_threshold : float
        Evidence at which a fault is published, nats.
    fault_ratio : float
        This window's log-likelihood ratio of some fault against healthy, nats
        (``fault_log_ratio``, before the allowance).
    evidence_weight : float
        The share of one window length the window counts for in the sequential test (0..1:
        its excitation weight times hop / window); 0 for a window that gives no evidence.
    """

    t_s: float
    label: str
    raw_label: str
    probabilities: dict[str, float]
    confidence: float
    window_s: float
    t_start_s: float
    distance: float
    reason: str = ""
    covered: bool = True
    coverage_distance: float = 0.0
    fault_evidence: float = 0.0
    fault_candidate: str = ""
    fault_threshold: float = math.inf
    fault_ratio: float = 0.0
    evidence_weight: float = 0.0


class DiagnosisStream:
    """Online diagnosis of one thruster: residual samples in, a Decision every hop.

    Parameters
    ----------
    model : ClassifierModel
        The exported classifier.
    hop_s : float
        Time between decisions once a window is full, s (rounded to whole samples).
    hysteresis : int
        The published healthy label changes only when this many consecutive informative
        windows agree on a new one.
    unknown_threshold : float or None
        Top probability under which a window (and the healthy evidence) is unknown; None uses
        the card's.
    evidence_tau_s : float
        Time constant of the healthy-class evidence, s of excited operation
        (``EVIDENCE_TAU_S``); 0 follows each window's own answer.
    excitation_range : (float, float)
        ``active_fraction`` below which a window weighs 0 and above which it weighs 1
        (``EXCITATION_RANGE``).
    false_alarms_per_hour : float
        False-alarm rate the fault threshold is set for (``fault_threshold``), per hour.
    unit_allowance : float
        Allowance of the sequential test, nats per window length (``UNIT_ALLOWANCE``).

    Decision layer. A window is *informative* when the rotor turned (excitation weight
    ``w > 0``, from its share of turning samples) at a mean |command| of at least the
    classifier's evidence floor (``ClassifierModel.min_command_abs``), its operating point is
    covered by the training region (``ClassifierModel.coverage``) and its features are like
    some class; any other window is published as ``"unknown"`` with the reason and changes no
    evidence.
    Informative windows feed two kinds of evidence:

    - faults, by a sequential test: the log-likelihood ratio ``llr`` of the fault classes
      together against the healthy ones, ``log(p_F / p_H) + log(pi_H / pi_F)`` (the calibrated
      probabilities with the training's equal class priors), clipped to ``LLR_CLIP``, less
      ``unit_allowance``, weighted by ``w * hop / window_s``, enters a CUSUM ``S``. A fault is
      published once ``S`` reaches ``fault_threshold(false_alarms_per_hour, window_s)``, as the
      fault class with the most accumulated evidence (the weighted mean of log-probabilities
      below); it stands until a CUSUM of the opposite step reaches the same threshold (then the
      fault evidence restarts);
    - healthy classes: each window's log-probabilities enter an exponentially weighted mean
      (forgetting only while the thruster turns); the label is the healthy class with the
      largest softmax of that mean, ``"unknown"`` (``evidence_pending``) when the healthy
      classes together fall under ``unknown_threshold``, with hysteresis.

    ``raw_label`` and ``probabilities`` of a Decision stay the window's own (coverage
    ignored); ``confidence`` is the evidence's probability of the published class (the window's
    top probability when the label is ``"unknown"``), within [P_MIN, 1 - P_MIN].
    """

    def __init__(
        self,
        model: ClassifierModel,
        *,
        hop_s: float = 1.0,
        hysteresis: int = 2,
        unknown_threshold: float | None = None,
        evidence_tau_s: float = EVIDENCE_TAU_S,
        excitation_range: tuple[float, float] = EXCITATION_RANGE,
        false_alarms_per_hour: float = FALSE_ALARMS_PER_HOUR,
        unit_allowance: float = UNIT_ALLOWANCE,
    ) -> None:
        if not (math.isfinite(hop_s) and hop_s > 0):
            raise ValueError(f"hop_s must be > 0, got {hop_s}")
        if not (math.isfinite(evidence_tau_s) and evidence_tau_s >= 0):
            raise ValueError(f"evidence_tau_s must be >= 0, got {evidence_tau_s}")
        lo, hi = (float(v) for v in excitation_range)
        if not (0.0 <= lo < hi <= 1.0):
            raise ValueError(f"excitation_range must satisfy 0 <= lo < hi <= 1, got {lo}, {hi}")
        if hysteresis < 1:
            raise ValueError(f"hysteresis must be >= 1, got {hysteresis}")
        if unknown_threshold is not None and not 0.0 <= unknown_threshold <= 1.0:
            raise ValueError(f"unknown_threshold must be in [0, 1], got {unknown_threshold}")
        if not (math.isfinite(unit_allowance) and 0.0 <= unit_allowance <= LLR_CLIP):
            raise ValueError(f"unit_allowance must be in [0, {LLR_CLIP:.1f}], got {unit_allowance}")
        self.model = model
        self.hop_s = hop_s
        self.hysteresis = hysteresis
        self.unknown_threshold = (
            model.probability_threshold if unknown_threshold is None else unknown_threshold
        )
        self.evidence_tau_s = float(evidence_tau_s)
        self.excitation_range = (lo, hi)
        self.threshold = fault_threshold(false_alarms_per_hour, model.window_s)
        self.unit_allowance = float(unit_allowance)
        hop_samples = max(1, round(hop_s / model.sample_time_s))
        self._hop_time_s = hop_samples * model.sample_time_s
        self._gamma = min(self._hop_time_s / model.window_s, 1.0)
        self._windows = WindowFeaturizer(model.window_samples, hop_samples, model.sample_time_s)
        self._active_index = FEATURE_NAMES.index("active_fraction")
        self._load_index = OPERATING_POINT.index("command_abs_mean")
        names = model.class_names
        self._faults = np.array([c in FAULT_CLASSES for c in names])
        if not self._faults.any() or self._faults.all():
            raise ValueError("the classifier needs healthy and fault classes")
        self._class_counts = (int((~self._faults).sum()), int(self._faults.sum()))
        self.reset()

    def reset(self) -> None:
        """Forget the window, the evidence and the label history (the label returns to
        ``"unknown"``)."""
        self._windows.reset()
        self._recent: deque[str] = deque(maxlen=self.hysteresis)
        self._label = UNKNOWN
        self._log_p = np.zeros(len(self.model.class_names))
        self._weight = 0.0
        self._unlike = 0.0
        self._cusum = 0.0
        self._declared = False
        self._clear = 0.0

    def push(
        self,
        t_s: float,
        command: float,
        voltage: float,
        rpm: float,
        current: float,
        residual_rpm: float,
        residual_current: float,
        valid: bool,
    ) -> Decision | None:
        """Feed one residual sample (``nominal.residuals.ResidualSample`` + its command, voltage).

        Parameters
        ----------
        t_s : float
            Sample time, s.
        command, voltage, rpm, current : float
            The telemetry sample: -1..1, V, rpm, A.
        residual_rpm, residual_current : float
            Measured minus predicted rpm and current (A).
        valid : bool
            ``ResidualSample.valid``; invalid samples are skipped.

        Returns
        -------
        Decision or None
            A decision every ``hop_s`` once a window is full, else None. A time gap restarts
            the window (the label and the evidence are kept).
        """
        out = self._windows.push(
            t_s, (command, voltage, rpm, current, residual_rpm, residual_current), valid
        )
        if out is None:
            return None
        return self._decide(*out)

    def _decide(
        self, t_start: float, t_end: float, features: np.ndarray, point: np.ndarray
    ) -> Decision:
        probs, dist = self.model.predict_proba(features[None])
        p = probs[0]
        best = int(np.argmax(p))
        distance = float(dist[0])
        unlike = distance > self.model.distance_threshold
        raw = (
            UNKNOWN if unlike or p[best] < self.unknown_threshold else self.model.class_names[best]
        )
        covered, coverage_distance = self.model.coverage.covers(point)
        lo, hi = self.excitation_range
        active = float(features[self._active_index])
        w = min(max((active - lo) / (hi - lo), 0.0), 1.0) if math.isfinite(active) else 0.0
        if point[self._load_index] < self.model.min_command_abs:
            w = 0.0
        llr = fault_log_ratio(float(p[self._faults].sum()), *self._class_counts)
        weight = 0.0
        if w <= 0.0:
            reason = LOW_EXCITATION
        elif not covered:
            reason = OUTSIDE_TRAINING
        elif unlike:
            reason = UNLIKE_CLASSES
        else:
            weight = w * self._gamma
            reason = self._add_evidence(p, llr, w)
        label = self._label if reason == "" else UNKNOWN
        confidence = self._probability_of(label) if label != UNKNOWN else float(p[best])
        evidence = self._cusum
        return Decision(
            t_s=t_end,
            label=label,
            raw_label=raw,
            probabilities={c: float(v) for c, v in zip(self.model.class_names, p, strict=True)},
            confidence=min(max(confidence, P_MIN), 1.0 - P_MIN),
            window_s=self.model.window_s,
            t_start_s=t_start,
            distance=distance,
            reason=reason if label == UNKNOWN else "",
            covered=covered,
            coverage_distance=coverage_distance,
            fault_evidence=evidence,
            fault_candidate=self._fault_candidate() if evidence > 0.0 else "",
            fault_threshold=self.threshold,
            fault_ratio=llr,
            evidence_weight=weight,
        )

    def _add_evidence(self, p: np.ndarray, llr: float, w: float) -> str:
        """Add one informative window (probabilities (C,), its fault log-likelihood ratio,
        weight 0..1); set the label; return the reason it is unknown, or ``""``."""
        step = w * self._gamma * (llr - self.unit_allowance)
        self._cusum = min(max(self._cusum + step, 0.0), 2.0 * self.threshold)
        keep = math.exp(-w * self._hop_time_s / self.evidence_tau_s) if self.evidence_tau_s else 0
        self._log_p = keep * self._log_p + w * np.log(p)
        self._weight = keep * self._weight + w
        if self._declared:
            self._clear = max(self._clear - step, 0.0)
            if self._clear >= self.threshold:
                self._declared = False
                self._cusum = 0.0
                self._clear = 0.0
        elif self._cusum >= self.threshold:
            self._declared = True
            self._clear = 0.0
        if self._declared:
            self._label = self._fault_candidate()
            self._recent.clear()
            return ""
        q = self._evidence_probabilities()
        healthy = np.where(self._faults, -1.0, q)
        candidate = self.model.class_names[int(np.argmax(healthy))]
        if float(q[~self._faults].sum()) < self.unknown_threshold:
            self._recent.clear()
            self._label = UNKNOWN
            return EVIDENCE_PENDING
        self._recent.append(candidate)
        if self._label in FAULT_CLASSES or self._label == UNKNOWN:
            self._label = candidate  # no healthy label yet, or a fault just cleared
        elif len(self._recent) == self.hysteresis and len(set(self._recent)) == 1:
            self._label = candidate
        return ""

    def _fault_candidate(self) -> str:
        """The fault class with the largest accumulated evidence."""
        faults = np.where(self._faults, self._log_p, -np.inf)
        return self.model.class_names[int(np.argmax(faults))]

    def _evidence_probabilities(self) -> np.ndarray:
        """Softmax (C,) of the weighted mean log-probability of the informative windows."""
        mean = self._log_p / self._weight
        q = np.exp(mean - mean.max())
        return q / q.sum()

    def _probability_of(self, label: str) -> float:
        if self._weight <= 0.0:
            return 0.0
        return float(self._evidence_probabilities()[self.model.class_names.index(label)])
