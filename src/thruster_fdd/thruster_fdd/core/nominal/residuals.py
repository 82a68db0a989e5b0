"""Residuals of a telemetry stream against the nominal model, without ROS.

:class:`ResidualStream` is what the ``nominal_model`` node (and offline diagnosis) runs per
telemetry sample: it feeds the model at the model's own sample time (telemetry faster than that
is decimated), resets the model's lookback on a gap in time or sequence, refuses non-finite or
out-of-range samples, and flags every output so that no NaN is ever produced. Every residual of a
warm-up that follows a reset (a gap, a refused sample, a diverged prediction) is flagged
``STATE_RESET`` as well as ``WARMING_UP``: ``WARMING_UP`` alone is only the model's first warm-up,
so a consumer that sees it knows that nothing came before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

OK = 0


WARMING_UP = 1


STATE_RESET = 2


INPUT_INVALID = 4
"""Flags of a residual, equal to ``thruster_fdd_msgs/Residual`` OK / WARMING_UP / ... ."""


# Decimation accepts a sample this much earlier than one model period after the last one, so
# jitter in telemetry stamps does not skip every other sample.
_PERIOD_TOLERANCE = 0.1


def too_soon(dt_s: float, period_s: float) -> bool:
    """Whether a sample ``dt_s`` after the last fed one falls within the model period."""
    return 0.0 <= dt_s < (1.0 - _PERIOD_TOLERANCE) * period_s


def decimate(t: np.ndarray, period_s: float) -> np.ndarray:
    """Which samples a :class:`ResidualStream` feeds to its model (valid, gap-free input).

    Parameters
    ----------
    t : np.ndarray, shape (n,)
        Sample times, s, increasing.
    period_s : float
        The model's sample time, s.

    Returns
    -------
    np.ndarray of bool, shape (n,)
        True for the samples that produce a residual.
    """
    keep = np.zeros(len(t), dtype=bool)
    last: float | None = None
    for i, ti in enumerate(t.tolist()):
        if last is None or not too_soon(ti - last, period_s):
            keep[i] = True
            last = ti
    return keep


class SteppableModel(Protocol):
    """What :class:`ResidualStream` needs of a nominal model (``nominal.runtime.NominalModel``)."""

    sample_time_s: float

    def reset(self) -> None: ...

    def step(
        self, command: float, voltage: float, rpm: float, current: float
    ) -> tuple[float, float] | None: ...


@dataclass(frozen=True)
class InputLimits:
    """Plausible telemetry for the model's inputs; outside them a sample is refused.

    Attributes
    ----------
    voltage_v : tuple of float
        Bus voltage range, V.
    rpm : float
        Largest plausible |rpm|.
    current_a : float
        Largest plausible |current|, A.
    """

    voltage_v: tuple[float, float] = (5.0, 30.0)
    rpm: float = 10_000.0
    current_a: float = 60.0

    def problems(self, command: float, voltage: float, rpm: float, current: float) -> str:
        """Why the sample is unusable, or an empty string."""
        values = {"command": command, "voltage": voltage, "rpm": rpm, "current": current}
        bad = [name for name, value in values.items() if not math.isfinite(value)]
        if bad:
            return f"non-finite {', '.join(bad)}"
        if abs(command) > 1.0 + 1e-9:
            return f"command {command:g} outside -1..1"
        if not self.voltage_v[0] <= voltage <= self.voltage_v[1]:
            return f"voltage {voltage:g} V outside {self.voltage_v[0]:g}..{self.voltage_v[1]:g}"
        if abs(rpm) > self.rpm:
            return f"|rpm| {abs(rpm):g} above {self.rpm:g}"
        if abs(current) > self.current_a:
            return f"|current| {abs(current):g} A above {self.current_a:g}"
        return ""


@dataclass(frozen=True)
class ResidualSample:
    """One residual: measured, predicted and their difference (measured - predicted).

    Predicted and residual values are 0 when ``flags`` says there is no prediction
    (WARMING_UP or INPUT_INVALID); non-finite measurements are reported as 0.
    """

    t_s: float
    measured_rpm: float
    predicted_rpm: float
    residual_rpm: float
    measured_current_a: float
    predicted_current_a: float
    residual_current_a: float
    flags: int
    reason: str = ""

    @property
    def valid(self) -> bool:
        """True when the residual comes from a prediction (no WARMING_UP / INPUT_INVALID)."""
        return not self.flags & (WARMING_UP | INPUT_INVALID)


def _finite(x: float) -> float:
    return x if math.isfinite(x) else 0.0


class ResidualStream:
    """Feeds telemetry to a nominal model at its sample time and returns residuals.

    Parameters
    ----------
    model : SteppableModel
        The nominal model (stateful; reset here on gaps).
    max_gap_periods : float
        A time step longer than this many model periods resets the model's state.
    limits : InputLimits
        Plausible input ranges.
    """

    def __init__(
        self,
        model: SteppableModel,
        max_gap_periods: float = 3.0,
        limits: InputLimits | None = None,
    ) -> None:
        if max_gap_periods <= 1.0:
            raise ValueError(f"max_gap_periods must be > 1, got {max_gap_periods}")
        self._model = model
        self._period = float(model.sample_time_s)
        self._max_gap_s = max_gap_periods * self._period
        self._limits = limits or InputLimits()
        self._last_t: float | None = None
        self._last_seq: int | None = None
        self._after_reset = False
        self.resets = 0
        self.invalid = 0

    def reset(self) -> None:
        """Forget the past: the model's lookback fills again from the next sample, and the
        residuals of that warm-up are flagged ``STATE_RESET``."""
        self._model.reset()
        self._last_t = None
        self._last_seq = None
        self._after_reset = True

    def push(
        self,
        t_s: float,
        command: float,
        voltage: float,
        rpm: float,
        current: float,
        sequence: int | None = None,
    ) -> ResidualSample | None:
        """Process one telemetry sample.

        Parameters
        ----------
        t_s : float
            Sample time, s (monotonic within a stream).
        command, voltage, rpm, current : float
            Applied command (-1..1), bus voltage (V), rpm, bus current (A).
        sequence : int or None
            The driver's sequence number; a number lower than the previous one (a restarted
            driver or bridge) resets the state.

        Returns
        -------
        ResidualSample or None
            None when the sample falls between two model periods (decimated away).
        """
        flags = 0
        reason = self._limits.problems(command, voltage, rpm, current)
        if reason:
            self.invalid += 1
            self.reset()
            return ResidualSample(
                t_s, _finite(rpm), 0.0, 0.0, _finite(current), 0.0, 0.0, INPUT_INVALID, reason
            )
        if self._last_t is not None:
            dt = t_s - self._last_t
            if too_soon(dt, self._period):
                return None
            if dt < 0.0 or dt > self._max_gap_s:
                reason = f"time gap of {dt:.3f} s"
        going_back = None not in (self._last_seq, sequence) and sequence < self._last_seq
        if not reason and going_back:
            reason = f"sequence went back from {self._last_seq} to {sequence}"
        if reason:
            self.resets += 1
            self.reset()
            flags |= STATE_RESET
        self._last_t = t_s
        self._last_seq = sequence
        prediction = self._model.step(command, voltage, rpm, current)
        if prediction is None:
            if self._after_reset:
                flags |= STATE_RESET
            return ResidualSample(t_s, rpm, 0.0, 0.0, current, 0.0, 0.0, flags | WARMING_UP, reason)
        self._after_reset = False
        pred_rpm, pred_current = prediction
        if not (math.isfinite(pred_rpm) and math.isfinite(pred_current)):
            self.reset()
            return ResidualSample(
                t_s, rpm, 0.0, 0.0, current, 0.0, 0.0, flags | INPUT_INVALID, "model diverged"
            )
        return ResidualSample(
            t_s,
            rpm,
            pred_rpm,
            rpm - pred_rpm,
            current,
            pred_current,
            current - pred_current,
            flags,
            reason,
        )
