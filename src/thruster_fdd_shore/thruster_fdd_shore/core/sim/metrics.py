"""What a step or a sine does to a simulated (or measured) thruster: dead time, settling,
overshoot, hysteresis loop area (the paper's facts the ``t100`` preset reproduces).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StepMetrics:
    """Response of one command step (times from the command change, s).

    Attributes
    ----------
    t_step : float
        Time of the command change, s.
    command_from, command_to : float
        Command before and after the step.
    dead_time_s : float
        Until the speed has moved 2 % of the step's speed change.
    settling_time_s : float
        Until the speed stays within 2 % of the step's speed change around the final value.
    overshoot : float
        Largest excursion beyond the final value, as a fraction of the speed change (>= 0).
    """

    t_step: float
    command_from: float
    command_to: float
    dead_time_s: float
    settling_time_s: float
    overshoot: float


def step_metrics(
    t: np.ndarray, command: np.ndarray, rpm: np.ndarray, *, band: float = 0.02
) -> list[StepMetrics]:
    """Measure dead time, settling time and overshoot of every command step in a trace.

    Parameters
    ----------
    t, command, rpm : np.ndarray, shape (n,)
        Sample times (s), commands, speeds (rpm); each step must be held until settled.
    band : float
        Relative band for dead time and settling (0.02: the 2 % criterion).

    Returns
    -------
    list of StepMetrics
        One per step whose speed change exceeds 50 rpm; initial and final speeds are averages
        over the last second before the step and before the next step.
    """
    t, command, rpm = (np.asarray(a, dtype=float) for a in (t, command, rpm))
    changes = np.flatnonzero(np.diff(command) != 0.0) + 1
    bounds = [*list(changes), len(t)]
    out = []
    for k, start in enumerate(changes):
        end = bounds[k + 1]
        before = (t >= t[start] - 1.0) & (t < t[start])
        after = (t >= t[end - 1] - 1.0) & (np.arange(len(t)) < end)
        initial, final = rpm[before].mean(), rpm[after].mean()
        change = final - initial
        if abs(change) < 50.0:
            continue
        seg_t = t[start - 1 : end] - t[start - 1]
        seg = rpm[start - 1 : end]
        moved = np.flatnonzero(np.abs(seg - initial) > band * abs(change))
        outside = np.flatnonzero(np.abs(seg - final) > band * abs(change))
        settle = seg_t[min(outside[-1] + 1, len(seg) - 1)] if len(outside) else 0.0
        out.append(
            StepMetrics(
                t_step=float(t[start - 1]),
                command_from=float(command[start - 1]),
                command_to=float(command[start]),
                dead_time_s=float(seg_t[moved[0]]) if len(moved) else math.nan,
                settling_time_s=float(settle),
                overshoot=float(max(0.0, np.max(np.sign(change) * (seg - final)) / abs(change))),
            )
        )
    return out


def hysteresis_loop_area(command: np.ndarray, rpm: np.ndarray, rpm_scale: float) -> float:
    """Area enclosed by a command-rpm loop (shoelace), with rpm divided by ``rpm_scale``.

    Parameters
    ----------
    command, rpm : np.ndarray, shape (n,)
        One full period of a periodic command and the resulting speed.
    rpm_scale : float
        Speed normalisation, rpm (e.g. the full-scale speed), so the area is dimensionless.
    """
    x = np.asarray(command, dtype=float)
    y = np.asarray(rpm, dtype=float) / rpm_scale
    return float(0.5 * abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))
