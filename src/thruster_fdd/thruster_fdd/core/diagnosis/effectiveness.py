"""Effectiveness of a thruster: thrust available now relative to a healthy thruster of its type at
the same command and supply (1.0 healthy, lower with broken blades or fouling), with an
uncertainty, from the telemetry the residuals carry (docs/diagnosis.md, "Effectiveness").

Method:

1. Reference curves (``diagnosis.reference.ThrustReference``): the thruster type's physics at
   steady state, for each fault family (blades lost 0..2, fouling 0..2) on a grid of
   severities and supply voltages: speed, electrical power ``V I`` and thrust against command.
   They are computed ashore and read from a folder beside the models.
2. Severity evidence (``EffectivenessEstimator.push``): each sample's measured power is compared
   with every severity's power at the measured speed. The load a propeller puts on its motor
   at a given speed does not depend on the command path (deadband, ESC lag, dead time) and
   measured power needs no parameter of the unit, so unit-to-unit spread enters only through
   the propeller itself. Squared errors, each over its variance, accumulate with forgetting
   over seconds of informative operation (the rotor turning faster than ``MIN_SPEED_FRACTION``
   of the healthy top speed): a thruster that idles keeps its estimate.
3. Severity: the least accumulated error on the grid, refined by a parabola, in the family that
   fits better (blades lighten the load, fouling adds to it; both meet at 0). The classifier's
   label is not used: the load says the family unambiguously wherever it matters, and a wrong
   label cannot mislead the estimate.
4. Effectiveness: the least-squares gain of the reference thrust at that severity against the
   healthy reference thrust over the last ``window_s`` of commands, the number by which a thrust
   allocator scales the thruster's column. Its uncertainty combines the severity's, a floor for
   what the curves cannot know about the unit, and a share of the thrust loss for a fault whose
   thrust differs from what its load implies (only the load is measured).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from thruster_fdd.core.diagnosis.reference import (
    FAULT_FAMILIES,
    MAX_SEVERITY,
    SEVERITY_STEP,
    ThrustReference,
)

MIN_CHANGE = 0.2
"""Smallest departure of the recent severity (blades lost, fouling level) that counts as a
change of the fault (``EffectivenessEstimator``)."""

_RAD_S_TO_RPM = 60.0 / (2.0 * math.pi)
_TYPICAL = np.linspace(0.3, 1.0, 8)  # commands for the gain when the window asks no thrust


@dataclass(frozen=True)
class Effectiveness:
    """One effectiveness estimate.

    Attributes
    ----------
    value : float
        Thrust available relative to a healthy thruster at the same command and supply (1.0
        healthy), over the last window's commands.
    std : float
        Its standard uncertainty (1 sigma), same unit.
    family : str
        ``"blades"``, ``"fouling"``, or ``""`` when there is no evidence yet.
    severity : float
        Fitted severity of ``family``: blades lost, or fouling in units of the ``biofouling``
        class (0 healthy).
    severity_std : float
        Its standard uncertainty.
    evidence_s : float
        Seconds of informative operation behind the estimate (forgetting applied).
    """

    value: float
    std: float
    family: str
    severity: float
    severity_std: float
    evidence_s: float


NO_EVIDENCE = Effectiveness(1.0, 0.5, "", 0.0, MAX_SEVERITY / 2, 0.0)
"""What is said before the rotor has turned: healthy, with an uncertainty that spans faults."""


class _Evidence:
    """Accumulated, forgetting severity evidence of both families at one time constant."""

    def __init__(self, n_severities: int, memory_s: float) -> None:
        self.memory_s = memory_s
        self.sse = {f: np.zeros(n_severities) for f in FAULT_FAMILIES}
        self.weight = 0.0
        self.seconds = 0.0

    def add(self, dt: float, errors: dict[str, np.ndarray]) -> None:
        """One informative sample ``dt`` s after the previous: normalised squared errors (K,)."""
        keep = math.exp(-dt / self.memory_s)
        for family, err2 in errors.items():
            self.sse[family] = keep * self.sse[family] + err2
        self.weight = keep * self.weight + 1.0
        self.seconds = keep * self.seconds + dt

    def copy_from(self, other: _Evidence) -> None:
        """Take ``other``'s evidence (a change was detected: the old evidence is obsolete)."""
        self.sse = {f: v.copy() for f, v in other.sse.items()}
        self.weight = other.weight
        self.seconds = other.seconds

    def fit(self, severities: np.ndarray, correlation_s: float) -> tuple[str, float, float]:
        """Best family, its severity and the severity's standard uncertainty."""
        family = min(FAULT_FAMILIES, key=lambda f: float(self.sse[f].min()))
        mse = self.sse[family] / self.weight
        severity, curvature = _parabolic_minimum(severities, mse)
        # Independent samples behind the evidence: informative seconds over the correlation
        # time; a poor best fit (mean normalised error above 1) widens the uncertainty.
        n_indep = max(self.seconds / correlation_s, 1.0)
        scale = max(float(mse.min()), 1.0)
        if curvature <= 0.0:
            return family, severity, MAX_SEVERITY
        return family, severity, min(math.sqrt(2.0 * scale / (n_indep * curvature)), MAX_SEVERITY)


class EffectivenessEstimator:
    """Online effectiveness of one thruster (see the module docstring).

    Two evidence accumulators run side by side, a slow one (``memory_s``) that gives the
    estimate and a fast one (``change_memory_s``); when the fast one's severity departs from
    the slow one's by more than ``change_z`` of its uncertainty (and ``MIN_CHANGE``), the slow
    one restarts from the fast one's evidence: a fault that appears mid-run is followed in
    seconds, not after the old evidence has faded.

    Parameters
    ----------
    reference : ThrustReference
        Reference curves of the thruster type.
    memory_s : float
        Time constant of the severity evidence, s of informative operation.
    change_memory_s : float
        Time constant of the fast evidence that detects a change, s.
    change_z : float
        Departure of the fast severity from the slow one, in the fast one's standard
        uncertainties, that counts as a change.
    window_s : float
        Span of recent commands over which the thrust gain is taken, s.
    floor_std : float
        Least uncertainty of the effectiveness (what the curves cannot know about the unit).
    loss_rel_std : float
        Uncertainty of the thrust loss ``1 - value`` as a share of it: how far a fault's thrust
        may stray from what its load implies.
    power_noise_w : float
        Absolute part of a sample's power error, W.
    power_rel_error : float
        Relative part of a sample's power error (unit spread, ripple, transients).
    correlation_s : float
        Time over which consecutive samples' errors are taken as dependent, s (for the
        severity's uncertainty).
    """

    def __init__(
        self,
        reference: ThrustReference,
        *,
        memory_s: float = 60.0,
        change_memory_s: float = 8.0,
        change_z: float = 3.0,
        window_s: float = 30.0,
        floor_std: float = 0.03,
        loss_rel_std: float = 0.25,
        power_noise_w: float = 1.0,
        power_rel_error: float = 0.03,
        correlation_s: float = 2.0,
    ) -> None:
        for name, value in (
            ("memory_s", memory_s),
            ("change_memory_s", change_memory_s),
            ("window_s", window_s),
            ("correlation_s", correlation_s),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0 s, got {value}")
        self.reference = reference
        self.memory_s = memory_s
        self.change_memory_s = change_memory_s
        self.change_z = change_z
        self.window_s = window_s
        self.floor_std = floor_std
        self.loss_rel_std = loss_rel_std
        self.power_noise_w = power_noise_w
        self.power_rel_error = power_rel_error
        self.correlation_s = correlation_s
        self.changes = 0
        self._recent: deque[tuple[float, float, float]] = deque()  # (t s, command, voltage V)
        self.reset()

    def reset(self) -> None:
        """Forget every sample and all evidence."""
        k = len(self.reference.severities)
        self._slow = _Evidence(k, self.memory_s)
        self._fast = _Evidence(k, self.change_memory_s)
        self._next_check_s = self.change_memory_s
        self._last_t: float | None = None
        self._recent.clear()

    def push(self, t_s: float, command: float, voltage: float, rpm: float, current: float) -> None:
        """Add one telemetry sample (s, -1..1, V, rpm, A); non-finite samples are skipped."""
        if not all(math.isfinite(x) for x in (t_s, command, voltage, rpm, current)):
            return
        if voltage <= 0.0:
            return
        dt = 0.0 if self._last_t is None else min(max(t_s - self._last_t, 0.0), 1.0)
        self._last_t = t_s
        self._recent.append((t_s, command, voltage))
        while self._recent and self._recent[0][0] < t_s - self.window_s:
            self._recent.popleft()
        speed = abs(rpm) / _RAD_S_TO_RPM
        reverse = rpm < 0.0
        # Braking (the rotor turning against the command) draws no propeller load.
        if dt <= 0.0 or (command != 0.0 and (command < 0.0) != reverse):
            return
        tables = [self.reference.curves(f, voltage, reverse) for f in FAULT_FAMILIES]
        if speed < tables[0].informative_speed:
            return
        power = voltage * current
        var = self.power_noise_w**2 + (self.power_rel_error * power) ** 2
        errors = {}
        for family, curves in zip(FAULT_FAMILIES, tables, strict=True):
            err = curves.power_at(speed) - power
            errors[family] = err * err / var
        self._slow.add(dt, errors)
        self._fast.add(dt, errors)
        self._next_check_s -= dt
        if self._next_check_s <= 0.0:
            self._next_check_s = 1.0
            self._detect_change()

    def _detect_change(self) -> None:
        severities = self.reference.severities
        fam_s, sev_s, _ = self._slow.fit(severities, self.correlation_s)
        fam_f, sev_f, std_f = self._fast.fit(severities, self.correlation_s)
        signed_s = sev_s if fam_s == FAULT_FAMILIES[0] else -sev_s
        signed_f = sev_f if fam_f == FAULT_FAMILIES[0] else -sev_f
        if abs(signed_f - signed_s) > max(self.change_z * std_f, MIN_CHANGE):
            self._slow.copy_from(self._fast)
            self.changes += 1

    def estimate(self) -> Effectiveness:
        """The effectiveness now (``NO_EVIDENCE`` before the rotor has turned)."""
        if self._slow.weight <= 0.0:
            return NO_EVIDENCE
        family, severity, severity_std = self._slow.fit(
            self.reference.severities, self.correlation_s
        )
        gains = self._gains(family)
        value = float(np.interp(severity, self.reference.severities, gains))
        slope = float(np.max(np.abs(np.diff(gains)))) / SEVERITY_STEP
        loss_std = self.loss_rel_std * max(1.0 - value, 0.0)
        std = math.sqrt(self.floor_std**2 + (slope * severity_std) ** 2 + loss_std**2)
        return Effectiveness(value, std, family, severity, severity_std, self._slow.seconds)

    def _gains(self, family: str) -> np.ndarray:
        """Least-squares thrust gain of every severity over the recent commands, shape (K,)."""
        voltage = float(np.median([v for _, _, v in self._recent])) if self._recent else 15.0
        commands = np.array([c for _, c, _ in self._recent])
        num = np.zeros(len(self.reference.severities))
        den = 0.0
        for reverse in (False, True):
            curves = self.reference.curves(family, voltage, reverse)
            magnitudes = np.abs(commands[commands < 0.0] if reverse else commands[commands > 0.0])
            if magnitudes.size == 0:
                continue
            thrust = curves.thrust_at(magnitudes)
            num += thrust @ thrust[0]
            den += float(thrust[0] @ thrust[0])
        if den <= 1e-9:  # no thrust asked for: the gain over typical commands, forward
            thrust = self.reference.curves(family, voltage, False).thrust_at(_TYPICAL)
            return thrust @ thrust[0] / float(thrust[0] @ thrust[0])
        return num / den


def _parabolic_minimum(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Minimum of ``y(x)`` on a uniform grid, refined by a parabola through its neighbours.

    Returns
    -------
    (x_min, curvature)
        The refined position and the second derivative there (0 when not convex), shape ().
    """
    k = int(np.argmin(y))
    h = float(x[1] - x[0])
    if 0 < k < len(x) - 1:
        y0, y1, y2 = float(y[k - 1]), float(y[k]), float(y[k + 1])
    elif k == 0:
        y0, y1, y2 = float(y[1]), float(y[0]), float(y[1])  # mirrored: the minimum sits at 0
    else:
        y0, y1, y2 = float(y[k - 1]), float(y[k]), float(y[k - 1])
    curvature = (y0 - 2.0 * y1 + y2) / (h * h)
    if curvature <= 0.0:
        return float(x[k]), 0.0
    offset = 0.5 * h * (y0 - y2) / (y0 - 2.0 * y1 + y2)
    return float(np.clip(x[k] + offset, x[0], x[-1])), curvature
