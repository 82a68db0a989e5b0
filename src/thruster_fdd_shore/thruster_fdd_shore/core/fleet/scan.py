"""One scan task: a recording through the vehicle's own code, one summary row per thruster.

The recording is read once, streaming (``stream.stream_recording``); per thruster, sample by
sample and from a reset state, exactly as on the vehicle:
``ResidualStream`` (nominal model) -> ``DiagnosisStream`` (classifier) for the published
decisions, and every telemetry sample into an ``EffectivenessEstimator`` (as the health node
does). Only running aggregates are kept (label durations, a fixed histogram of effectiveness,
sums of squared residuals per speed band, the label changes, at most ``MAX_EVENTS``), so what a
task holds is bounded by the pipelines' windows and the reader's reorder buffer, not by the
recording's length.
"""

from __future__ import annotations

import copy
import hashlib
import math
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from thruster_fdd.core.artifact import CARD_FILE
from thruster_fdd.core.diagnosis.effectiveness import EffectivenessEstimator
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.diagnosis.reference import ThrustReference
from thruster_fdd.core.diagnosis.stream import Decision, DiagnosisStream
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES, FAULT_CLASSES, UNKNOWN
from thruster_fdd.core.nominal.residuals import ResidualStream
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd_shore.core.diagnosis.offline import check_pair
from thruster_fdd_shore.core.fleet.archive import Recording, origin_s
from thruster_fdd_shore.core.fleet.stream import stream_recording

LABELS: tuple[str, ...] = (*CLASS_NAMES, UNKNOWN)
"""Labels whose share of time a row holds (``frac_<label>``)."""

SPEED_BANDS_RPM: tuple[tuple[str, float, float], ...] = (
    ("low", 0.0, 1000.0),
    ("mid", 1000.0, 2000.0),
    ("high", 2000.0, math.inf),
)
"""Speed bands (name, lower, upper |rpm|) of the residual RMS columns."""

MIN_EVIDENCE_S = 5.0
"""Effectiveness estimates with less informative operation behind them (s) are not counted."""

EFF_BINS = np.linspace(0.0, 1.5, 751)
"""Bin edges of the effectiveness histogram (width 0.002) its quantiles come from."""

MAX_EVENTS = 2000
"""Most label changes kept per row (the rest are counted in ``problems``)."""

ERROR_THRUSTER = "-"
"""Thruster of the error row of a recording that could not be read."""


@dataclass(frozen=True)
class ScanConfig:
    """What a scan task needs besides the recording.

    Attributes
    ----------
    models : str
        Folder with ``nominal/``, ``classifier/`` and ``reference/`` (absolute; a remote
        cluster's workers must see it at the same path).
    hop_s : float
        Time between decisions, s.
    hysteresis : int
        Consecutive agreeing windows before the published label changes.
    """

    models: str
    hop_s: float = 1.0
    hysteresis: int = 2


@dataclass(frozen=True)
class ModelPair:
    """The loaded models of a scan and their identities."""

    nominal: NominalModel
    classifier: ClassifierModel
    reference: ThrustReference
    digest: str

    @property
    def ids(self) -> dict[str, str]:
        """``nominal_model_id``, ``classifier_model_id``, ``reference_id``, ``models_digest``."""
        return {
            "nominal_model_id": self.nominal.model_id,
            "classifier_model_id": self.classifier.model_id,
            "reference_id": self.reference.name,
            "models_digest": self.digest,
        }


_LOADED: dict[str, ModelPair] = {}


def models_digest(models: str | Path) -> str:
    """SHA-256 (hex) over the three model cards (each lists its files' SHA-256)."""
    h = hashlib.sha256()
    for part in ("nominal", "classifier", "reference"):
        card = Path(models) / part / CARD_FILE
        if not card.is_file():
            raise BadInputError(f"{card}: missing (a models folder needs {part}/)")
        h.update(part.encode() + b"\0" + card.read_bytes())
    return h.hexdigest()


def load_pair(models: str | Path) -> ModelPair:
    """The models of a folder, loaded once per process (a worker keeps them between tasks).

    Raises
    ------
    BadInputError
        If a model is missing, does not load, or the classifier was made with another nominal
        model.
    """
    key = str(Path(models).absolute())
    if key not in _LOADED:
        digest = models_digest(key)
        nominal = NominalModel.load(Path(key) / "nominal")
        classifier = ClassifierModel.load(Path(key) / "classifier")
        check_pair(nominal, classifier, Path(key) / "classifier")
        reference = ThrustReference.load(Path(key) / "reference")
        _LOADED[key] = ModelPair(nominal, classifier, reference, digest)
    return _LOADED[key]


class ThrusterSummary:
    """Running aggregates of one thruster's decisions, effectiveness and residuals.

    Parameters
    ----------
    hop_s : float
        Time between decisions, s (the last decision stands this long).
    """

    def __init__(self, hop_s: float) -> None:
        self.hop_s = hop_s
        self.samples = 0
        self.t_first: float | None = None
        self.t_last = 0.0
        self.durations = dict.fromkeys(LABELS, 0.0)
        self.events: list[tuple[float, str]] = []
        self.dropped_events = 0
        self.first_fault: tuple[str, float] | None = None
        self.decisions = 0
        self.fault_p_sum = 0.0
        self.fault_p_max = 0.0
        self.confidence_sum = 0.0
        self.eff_hist = np.zeros(len(EFF_BINS) - 1, dtype=np.int64)
        n = len(SPEED_BANDS_RPM)
        self.sq = np.zeros((n, 2))  # sum of squared residuals, columns rpm and current (A)
        self.counts = np.zeros(n, dtype=np.int64)
        self._last: Decision | None = None

    def add_sample(self, t_s: float) -> None:
        """Count one telemetry sample at ``t_s`` (s)."""
        if self.t_first is None:
            self.t_first = t_s
        self.t_last = t_s
        self.samples += 1

    def add_residual(self, rpm: float, residual_rpm: float, residual_current_a: float) -> None:
        """A valid residual sample: measured rpm, residuals of rpm and current (A)."""
        speed = abs(rpm)
        for k, (_, lo, hi) in enumerate(SPEED_BANDS_RPM):
            if lo <= speed < hi:
                self.sq[k] += (residual_rpm * residual_rpm, residual_current_a**2)
                self.counts[k] += 1
                return

    def add_decision(self, d: Decision, effectiveness: float, evidence_s: float) -> None:
        """A published decision (only ``label``, ``t_s``, ``probabilities``, ``confidence``
        are read) and the effectiveness estimate at that moment."""
        if self._last is not None:
            self.durations[self._last.label] += max(d.t_s - self._last.t_s, 0.0)
        if self._last is None or d.label != self._last.label:
            if len(self.events) < MAX_EVENTS:
                self.events.append((d.t_s, d.label))
            else:
                self.dropped_events += 1
        if self.first_fault is None and d.label in FAULT_CLASSES:
            self.first_fault = (d.label, d.t_s)
        p_fault = sum(float(d.probabilities.get(c, 0.0)) for c in FAULT_CLASSES)
        self.fault_p_sum += p_fault
        self.fault_p_max = max(self.fault_p_max, p_fault)
        self.confidence_sum += float(d.confidence)
        self.decisions += 1
        if evidence_s >= MIN_EVIDENCE_S and math.isfinite(effectiveness):
            k = int(np.searchsorted(EFF_BINS, min(max(effectiveness, 0.0), 1.4999), "right"))
            self.eff_hist[k - 1] += 1
        self._last = d

    def _quantile(self, q: float) -> float | None:
        total = int(self.eff_hist.sum())
        if total == 0:
            return None
        k = int(np.searchsorted(np.cumsum(self.eff_hist), q * total, "left"))
        return float(0.5 * (EFF_BINS[k] + EFF_BINS[k + 1]))

    def row(self, origin_s: float) -> dict[str, Any]:
        """The summary's columns (times as s since the epoch; ``dataset.SCHEMA`` names)."""
        if self._last is not None:
            self.durations[self._last.label] += self.hop_s
        total = sum(self.durations.values())
        start = self.t_first if self.t_first is not None else 0.0
        row: dict[str, Any] = {
            "start_s": origin_s + start,
            "end_s": origin_s + self.t_last,
            "duration_s": self.t_last - start,
            "samples": self.samples,
            "decisions": self.decisions,
        }
        for label in LABELS:
            row[f"frac_{label}"] = self.durations[label] / total if total > 0 else None
        fault = self.first_fault
        row["first_fault_label"] = fault[0] if fault else None
        row["first_fault_s"] = origin_s + fault[1] if fault else None
        n = max(self.decisions, 1)
        row["fault_prob_mean"] = self.fault_p_sum / n if self.decisions else None
        row["fault_prob_max"] = self.fault_p_max if self.decisions else None
        row["confidence_mean"] = self.confidence_sum / n if self.decisions else None
        for q in (10, 50, 90):
            row[f"eff_q{q}"] = self._quantile(q / 100)
        for k, (band, _, _) in enumerate(SPEED_BANDS_RPM):
            c = int(self.counts[k])
            row[f"rms_rpm_{band}"] = math.sqrt(self.sq[k, 0] / c) if c else None
            row[f"rms_current_a_{band}"] = math.sqrt(self.sq[k, 1] / c) if c else None
        row["events"] = ";".join(f"{t - start:.3f}:{label}" for t, label in self.events)
        return row


class ThrusterScan:
    """One thruster's pipeline from a reset state, fed sample by sample, and its summary.

    Parameters
    ----------
    pair : ModelPair
        The models.
    config : ScanConfig
        Hop and hysteresis of the decisions.
    """

    def __init__(self, pair: ModelPair, config: ScanConfig) -> None:
        # The nominal model holds its input history: one copy per thruster fed interleaved.
        self.residuals = ResidualStream(copy.deepcopy(pair.nominal))
        self.residuals.reset()
        self.stream = DiagnosisStream(
            pair.classifier, hop_s=config.hop_s, hysteresis=config.hysteresis
        )
        self.estimator = EffectivenessEstimator(pair.reference)
        self.summary = ThrusterSummary(config.hop_s)

    def push(self, t: float, c: float, v: float, r: float, i: float) -> None:
        """One telemetry sample: s, command (-1..1), V, rpm, A (in time order)."""
        self.summary.add_sample(t)
        self.estimator.push(t, c, v, r, i)
        s = self.residuals.push(t, c, v, r, i)
        if s is None:
            return
        if s.valid:
            self.summary.add_residual(r, s.residual_rpm, s.residual_current_a)
        d = self.stream.push(t, c, v, r, i, s.residual_rpm, s.residual_current_a, s.valid)
        if d is not None:
            e = self.estimator.estimate()
            self.summary.add_decision(d, e.value, e.evidence_s)

    def row(self) -> dict[str, Any]:
        """The summary columns (times on the recording's clock, s) and the final effectiveness
        fit."""
        row = self.summary.row(0.0)
        e = self.estimator.estimate()
        row |= {
            "eff_last": e.value,
            "eff_std_last": e.std,
            "eff_family": e.family,
            "eff_severity": e.severity,
            "eff_evidence_s": e.evidence_s,
        }
        if self.summary.dropped_events:
            n = self.summary.dropped_events
            row["problems"] = f"{n} label change(s) beyond {MAX_EVENTS} not kept"
        return row


def scan_recording(recording: Recording, digest: str, config: ScanConfig) -> list[dict[str, Any]]:
    """The scan task: one row per thruster of a recording, or one error row when it cannot be
    read (bad input: a damaged or foreign file). A bug is not caught (Dask retries the task).

    Returns
    -------
    list of dict
        Rows with the columns of ``dataset.SCHEMA`` (times in s since the epoch).
    """
    pair = load_pair(config.models)
    base = {
        "vehicle": recording.vehicle,
        "recording": recording.relative,
        "digest": digest,
        "size_bytes": recording.size_bytes,
        "mtime_ns": recording.mtime_ns,
        "scanned_at_s": time.time(),
        **pair.ids,
    }
    scans: dict[str, ThrusterScan] = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            for tid, t, c, v, r, i in stream_recording(recording.path):
                scan = scans.get(tid)
                if scan is None:
                    scan = scans[tid] = ThrusterScan(pair, config)
                scan.push(t, c, v, r, i)
        except (BadInputError, OSError) as exc:
            return [base | {"thruster": ERROR_THRUSTER, "error": f"{type(exc).__name__}: {exc}"}]
    problems = "; ".join(dict.fromkeys(str(w.message) for w in caught))
    first = min((s.summary.t_first or 0.0 for s in scans.values()), default=0.0)
    origin = origin_s(recording.path, first)
    rows = []
    for tid in sorted(scans):
        row = base | {"thruster": tid} | scans[tid].row()
        for key in ("start_s", "end_s", "first_fault_s"):
            if row.get(key) is not None:
                row[key] += origin
        row["problems"] = "; ".join(p for p in (problems, row.get("problems") or "") if p)
        row["error"] = ""
        rows.append(row)
    return rows
