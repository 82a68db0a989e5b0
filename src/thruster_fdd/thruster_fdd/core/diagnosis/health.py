"""Vehicle-level thruster health, without ROS: each thruster's published diagnosis with a fault
flag and staleness, and its effectiveness estimate (``diagnosis.effectiveness``), as the health
node publishes them on ``/thruster_fdd/health`` (docs/contracts.md)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from thruster_fdd.core.diagnosis.effectiveness import Effectiveness, EffectivenessEstimator
from thruster_fdd.core.diagnosis.reference import ThrustReference
from thruster_fdd.core.labels import CLASS_NAMES, FAULT_CLASSES, UNKNOWN


@dataclass(frozen=True)
class ThrusterHealth:
    """The health of one thruster at one time.

    Attributes
    ----------
    thruster_id : str
        The thruster's id.
    label : str
        Its published diagnosis (a class name or ``"unknown"``; ``"unknown"`` when stale).
    condition : int
        ``label`` as the ``Diagnosis`` condition code (0 unknown, then ``CLASS_NAMES`` 1..6).
    confidence : float
        Probability of the published class, 0..1 (0 when stale).
    faulty : bool
        The label is a fault class (``labels.FAULT_CLASSES``).
    stale : bool
        No diagnosis for longer than the tracker's ``stale_after_s``.
    effectiveness : Effectiveness
        Thrust available relative to a healthy thruster, with its uncertainty.
    label_age_s : float
        Time since the diagnosis behind ``label`` arrived, s (grows while the classifier
        cannot tell and the last trustworthy label is kept).
    unknown_reason : str
        Reason of the latest diagnosis when it is unknown, ``""`` otherwise.
    """

    thruster_id: str
    label: str
    condition: int
    confidence: float
    faulty: bool
    stale: bool
    effectiveness: Effectiveness
    label_age_s: float = 0.0
    unknown_reason: str = ""


KEEP_REASONS = ("outside_training", "low_excitation")
"""Reasons of an unknown diagnosis under which the last trustworthy label stands: the classifier
cannot tell at this operating point, which says nothing against what it said before. Other
unknowns (unlike every class, evidence pending, stale) replace it."""


def masks(entries: Sequence[ThrusterHealth]) -> tuple[int, int]:
    """``(faulty_mask, stale_mask)``: bit i set when ``entries[i]`` is faulty / stale."""
    faulty = sum(1 << i for i, e in enumerate(entries) if e.faulty)
    stale = sum(1 << i for i, e in enumerate(entries) if e.stale)
    return faulty, stale


class HealthTracker:
    """Collects diagnoses and telemetry of several thrusters; health snapshots on demand.

    Parameters
    ----------
    thruster_ids : sequence of str
        The thrusters, in the order of the published list (at most 32: the masks are 32 bits).
    reference : ThrustReference
        Reference curves of the thruster type, shared by all thrusters.
    stale_after_s : float
        A thruster without a diagnosis for this long is stale (label unknown), s.
    """

    def __init__(
        self, thruster_ids: Sequence[str], reference: ThrustReference, stale_after_s: float
    ) -> None:
        ids = tuple(thruster_ids)
        if not ids or len(ids) > 32 or len(set(ids)) != len(ids):
            raise ValueError(f"need 1..32 distinct thruster ids, got {list(ids)}")
        if not stale_after_s > 0:
            raise ValueError(f"stale_after_s must be > 0, got {stale_after_s}")
        self.thruster_ids = ids
        self.stale_after_s = stale_after_s
        self._estimators = {tid: EffectivenessEstimator(reference) for tid in ids}
        self._latest: dict[str, tuple[str, str, float]] = {}  # label, reason, time s
        self._trusted: dict[str, tuple[str, float, float]] = {}  # label, confidence, time s
        self._published: dict[str, tuple[str, bool, bool]] = {}

    def add_diagnosis(
        self, thruster_id: str, label: str, confidence: float, now_s: float, reason: str = ""
    ) -> None:
        """A diagnosis of ``thruster_id`` arrived at ``now_s`` (the tracker's clock, s), with the
        reason when its label is unknown."""
        if thruster_id not in self._estimators:
            return
        self._latest[thruster_id] = (label, reason, now_s)
        if label != UNKNOWN:
            self._trusted[thruster_id] = (label, confidence, now_s)
        elif reason not in KEEP_REASONS:
            self._trusted.pop(thruster_id, None)

    def _current(self, tid: str, now_s: float) -> tuple[str, float, float, bool, str]:
        """Label, confidence, age s, stale, unknown reason of ``tid`` at ``now_s``."""
        latest = self._latest.get(tid)
        if latest is None or now_s - latest[2] > self.stale_after_s:
            return UNKNOWN, 0.0, 0.0, True, "stale" if latest else "no_diagnosis"
        label, reason, _ = latest
        trusted = self._trusted.get(tid)
        if trusted is None:
            return UNKNOWN, 0.0, 0.0, False, reason if label == UNKNOWN else ""
        return trusted[0], trusted[1], now_s - trusted[2], False, reason if label == UNKNOWN else ""

    def add_sample(
        self,
        thruster_id: str,
        t_s: float,
        command: float,
        voltage: float,
        rpm: float,
        current: float,
    ) -> None:
        """A telemetry sample of ``thruster_id`` (its own stamp s, -1..1, V, rpm, A)."""
        estimator = self._estimators.get(thruster_id)
        if estimator is not None:
            estimator.push(t_s, command, voltage, rpm, current)

    def snapshot(self, now_s: float) -> tuple[ThrusterHealth, ...]:
        """Every thruster's health at ``now_s`` (s, the clock of ``add_diagnosis``)."""
        out = []
        for tid in self.thruster_ids:
            label, confidence, age, stale, reason = self._current(tid, now_s)
            out.append(
                ThrusterHealth(
                    thruster_id=tid,
                    label=label,
                    condition=CLASS_NAMES.index(label) + 1 if label in CLASS_NAMES else 0,
                    confidence=float(confidence),
                    faulty=label in FAULT_CLASSES,
                    stale=stale,
                    effectiveness=self._estimators[tid].estimate(),
                    label_age_s=age,
                    unknown_reason=reason,
                )
            )
        return tuple(out)

    def changed(self, now_s: float) -> bool:
        """Whether a thruster's label, fault flag or staleness changed since the last call that
        returned True (the first call does)."""
        state = {}
        for tid in self.thruster_ids:
            label, _, _, stale, _ = self._current(tid, now_s)
            state[tid] = (label, label in FAULT_CLASSES, stale)
        if state == self._published:
            return False
        self._published = state
        return True
