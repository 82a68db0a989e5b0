"""Online diagnosis of one thruster: residual samples in, a ``Decision`` every hop.

Pipeline (the same online in the classifier node and offline in ``diagnosis.offline``)::

    telemetry --ResidualStream(nominal model)--> residual samples at the model's sample time
      --WindowFeaturizer--> one feature vector (diagnosis.features) per hop over the last window_s
      --ClassifierModel--> calibrated class probabilities + distance to the nearest class
      --DiagnosisStream--> raw label (class, or "unknown") -> evidence -> hysteresis -> Decision
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from thruster_fdd.core.diagnosis.features import FEATURE_NAMES, WINDOW_SIGNALS, window_features
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.labels import UNKNOWN

MAX_GAP_PERIODS = 3.0
"""A step longer than this many sample times between valid samples restarts the window."""


EVIDENCE_TAU_S = 5.0
"""Time constant of the decision layer's evidence accumulation, s of *excited* operation: each
window's log-probabilities enter an exponentially weighted mean that forgets at this rate only
while the thruster turns (tuned on validation units 400-405, docs/diagnosis.md)."""


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
    ) -> tuple[float, float, np.ndarray] | None:
        """Add one sample; every hop with a full window return ``(t_start, t_end, features)``.

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
        (t_start, t_end, features) or None
            Times of the window's first and last sample (s) and ``window_features`` (F,).
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
        return float(arr[0, 0]), float(arr[-1, 0]), window_features(arr[:, 1:], self.sample_time_s)


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
    """

    t_s: float
    label: str
    raw_label: str
    probabilities: dict[str, float]
    confidence: float
    window_s: float
    t_start_s: float
    distance: float


class DiagnosisStream:
    """Online diagnosis of one thruster: residual samples in, a Decision every hop.

    Parameters
    ----------
    model : ClassifierModel
        The exported classifier.
    hop_s : float
        Time between decisions once a window is full, s (rounded to whole samples).
    hysteresis : int
        The reported label changes only when this many consecutive evidence labels agree on a
        new one (``"unknown"`` included); it starts as ``"unknown"``.
    unknown_threshold : float or None
        Top probability under which a window is unknown; None uses the card's.
    evidence_tau_s : float
        Time constant of the evidence accumulation, s of excited operation
        (``EVIDENCE_TAU_S``); 0 turns accumulation off (the label follows the raw labels).
    excitation_range : (float, float)
        ``active_fraction`` below which a window weighs 0 and above which it weighs 1
        (``EXCITATION_RANGE``).

    Decision layer: each window's calibrated log-probabilities ``log p`` and its "unlike every
    class" flag enter exponentially weighted means with weight ``w`` (0..1, from the window's
    share of turning samples); the forgetting factor is ``exp(-w hop / evidence_tau_s)``, so a
    window without excitation neither adds evidence nor forgets it. The evidence label is the
    argmax of ``softmax(mean log p)`` (a weighted geometric mean of recent windows), or
    ``"unknown"`` when the weighted share of unlike windows exceeds 0.5 or its top probability
    is under ``unknown_threshold``; before any excited window it is the raw label. Hysteresis
    then acts on the evidence labels. ``raw_label``, ``probabilities`` and ``confidence`` of a
    Decision stay the window's own.
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
        self.model = model
        self.hop_s = hop_s
        self.hysteresis = hysteresis
        self.unknown_threshold = (
            model.probability_threshold if unknown_threshold is None else unknown_threshold
        )
        self.evidence_tau_s = float(evidence_tau_s)
        self.excitation_range = (lo, hi)
        hop_samples = max(1, round(hop_s / model.sample_time_s))
        self._hop_time_s = hop_samples * model.sample_time_s
        self._windows = WindowFeaturizer(model.window_samples, hop_samples, model.sample_time_s)
        self._recent: deque[str] = deque(maxlen=hysteresis)
        self._label = UNKNOWN
        self._active_index = FEATURE_NAMES.index("active_fraction")
        self._log_p = np.zeros(len(model.class_names))
        self._weight = 0.0
        self._unlike = 0.0

    def reset(self) -> None:
        """Forget the window, the evidence and the label history (the label returns to
        ``"unknown"``)."""
        self._windows.reset()
        self._recent.clear()
        self._label = UNKNOWN
        self._log_p = np.zeros(len(self.model.class_names))
        self._weight = 0.0
        self._unlike = 0.0

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
            the window (the label is kept).
        """
        out = self._windows.push(
            t_s, (command, voltage, rpm, current, residual_rpm, residual_current), valid
        )
        if out is None:
            return None
        t_start, t_end, features = out
        return self._decide(t_start, t_end, features)

    def _decide(self, t_start: float, t_end: float, features: np.ndarray) -> Decision:
        probs, dist = self.model.predict_proba(features[None])
        p = probs[0]
        best = int(np.argmax(p))
        confidence = float(p[best])
        distance = float(dist[0])
        unlike = distance > self.model.distance_threshold
        raw = (
            UNKNOWN
            if unlike or confidence < self.unknown_threshold
            else self.model.class_names[best]
        )
        evidence = self._evidence_label(features, p, unlike, raw)
        self._recent.append(evidence)
        if len(self._recent) == self.hysteresis and len(set(self._recent)) == 1:
            self._label = evidence
        return Decision(
            t_s=t_end,
            label=self._label,
            raw_label=raw,
            probabilities={c: float(v) for c, v in zip(self.model.class_names, p, strict=True)},
            confidence=confidence,
            window_s=self.model.window_s,
            t_start_s=t_start,
            distance=distance,
        )

    def _evidence_label(self, features: np.ndarray, p: np.ndarray, unlike: bool, raw: str) -> str:
        """Add one window to the accumulated evidence; the label it supports (class docstring)."""
        if self.evidence_tau_s == 0:
            return raw
        lo, hi = self.excitation_range
        active = float(features[self._active_index])
        w = min(max((active - lo) / (hi - lo), 0.0), 1.0) if math.isfinite(active) else 0.0
        if w > 0:
            keep = math.exp(-w * self._hop_time_s / self.evidence_tau_s)
            self._log_p = keep * self._log_p + w * np.log(np.maximum(p, 1e-9))
            self._weight = keep * self._weight + w
            self._unlike = keep * self._unlike + w * float(unlike)
        if self._weight <= 0:
            return raw
        mean = self._log_p / self._weight
        q = np.exp(mean - mean.max())
        q /= q.sum()
        best = int(np.argmax(q))
        if self._unlike / self._weight > 0.5 or q[best] < self.unknown_threshold:
            return UNKNOWN
        return self.model.class_names[best]
