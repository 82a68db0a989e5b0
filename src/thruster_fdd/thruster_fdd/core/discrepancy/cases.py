"""Synthetic measured traces with hidden effects, for tests, the study and the benchmark.

A case hides effects from the model: the "measured" trace is simulated (with unit spread,
noise, quantisation and outliers) from the t100 preset with the hidden effects set to random
plausible values; the model starts from the t100 preset without them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from thruster_fdd.core.discrepancy.search import start_config
from thruster_fdd.core.sim.config import (
    Measurement,
    SimConfig,
    load_config,
    perturb_unit,
    set_effect,
)
from thruster_fdd.core.sim.effects import make_effect
from thruster_fdd.core.sim.physics import simulate
from thruster_fdd.core.sim.signals import make_signal
from thruster_fdd.core.traces.data import Trace

PLAUSIBLE: dict[str, tuple[str, float, float]] = {
    "dead_time": ("delay_s", 0.3, 1.0),
    "deadband": ("width", 0.04, 0.12),
    "esc_lag": ("tau_s", 0.3, 1.0),
    "slew_rate_limit": ("rate_per_s", 0.5, 2.0),
    "coulomb_friction": ("torque_nm", 0.012, 0.025),
    "viscous_friction": ("coeff", 1.2e-4, 2.5e-4),
    "voltage_sag": ("r_internal_ohm", 0.1, 0.3),
    "current_limit": ("i_max_a", 6.0, 9.0),
}
"""Effect -> (parameter, low, high): uniform range of the hidden value for the t100 preset."""


SIGNALS = ("multilevel", "reversals", "lowspeed")
"""Command signals of the cases: ``multilevel`` (``core.sim.signals``: random levels held 2-15 s),
``reversals`` (fast large steps: alternating sign, |level| 0.6-1, held 3-8 s, so the duty is
asked to move by 1.2-2 at once) and ``lowspeed`` (linear ramps of 3-10 s between levels that
alternate between slow, |u| 0.08-0.35, and anywhere in -1..1: many zero crossings and a long
time at low speed, plus the full range)."""


EXCITING: dict[str, str] = {
    "slew_rate_limit": "reversals",
    "coulomb_friction": "lowspeed",
    "viscous_friction": "lowspeed",
    "current_limit": "reversals",
}
"""Effects that the default ``multilevel`` command does not excite, and the signal that does.

With the t100 ESC lag (0.61 s) a duty slew limit only binds on steps of more than
``rate * tau`` (1.2 at 2 /s), rare in ``multilevel``; there the lag absorbs it. Friction torques
are a few % of the propeller load at speed, where a re-fitted ``k_q`` and the other friction term
absorb them; they differ from it at low speed and around zero crossings. A current limit of
6-9 A binds only above |command| 0.75-0.9 (11 A at full command), which a 60 s ``multilevel``
command may never reach."""


@dataclass(frozen=True)
class Case:
    """One synthetic case.

    Attributes
    ----------
    trace : Trace
        The "measured" trace (noisy, one unit of the spread).
    start : SimConfig
        The model's starting configuration (t100 without the hidden effects).
    hidden : dict of str to dict of str to float
        Hidden effect -> its parameters in the simulated unit (after spread).
    signal : str
        The command signal (one of ``SIGNALS``).
    clean : Trace
        The same unit's response to the same command without measurement noise, outliers,
        quantisation or reporting floor: what a perfect model would output. Measured against
        it, a model's error has no noise floor (the study's "model error" column).
    """

    trace: Trace
    start: SimConfig
    hidden: dict[str, dict[str, float]]
    signal: str
    clean: Trace


ABSENT: dict[str, tuple[str, ...]] = {
    "coulomb_friction": ("viscous_friction",),
    "viscous_friction": ("coulomb_friction",),
}
"""Effects removed from both the truth and the model when the key is hidden.

The two friction torques absorb each other: over the measured speeds (above the 300 rpm
reporting floor) a viscous torque ``b w`` is matched within a few % by a re-fitted Coulomb
torque plus a re-fitted ``k_q w**2``, and a Coulomb torque by a viscous one. Measured (120 s):
hidden ``viscous_friction`` 4.9e-5 N m s/rad against t100 with its Coulomb term free, or hidden
``coulomb_friction`` 0.0065 N m against t100 with its viscous term free, leave the calibrated
model at the noise level (held-out score 0.97-1.10): nothing to find. So a friction case hides
one friction term from a model that has none (the t100 preset's other term is 1e-6 N m s/rad or
0.002 N m, removed from the truth too)."""


def case_signal(
    spec: str, duration_s: float, rate_hz: float, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Command of a case: one of ``SIGNALS`` (times from 0 s, command in -1..1)."""
    if spec == "multilevel":
        return make_signal("multilevel", duration_s, rate_hz, seed=seed)
    if spec not in SIGNALS:
        raise ValueError(f"unknown case signal {spec!r}; expected one of {', '.join(SIGNALS)}")
    n = max(1, round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    rng = np.random.default_rng([seed, 0x5161])
    knots_t, knots_u = [0.0], [0.0]
    sign = 1.0 if rng.random() < 0.5 else -1.0
    slow = True
    while knots_t[-1] < duration_s:
        if spec == "reversals":
            level = sign * rng.uniform(0.6, 1.0)
            sign = -sign
            knots_t += [knots_t[-1] + 1.0 / rate_hz, knots_t[-1] + rng.uniform(3.0, 8.0)]
            knots_u += [level, level]
        else:
            if slow:
                level = sign * rng.uniform(0.08, 0.35)
                sign = -sign
            else:
                level = rng.uniform(-1.0, 1.0)
            slow = not slow
            ramp = rng.uniform(3.0, 10.0)
            knots_t += [knots_t[-1] + ramp, knots_t[-1] + ramp + rng.uniform(1.0, 5.0)]
            knots_u += [level, level]
    return t, np.clip(np.interp(t, knots_t, knots_u), -1.0, 1.0)


def make_case(
    hidden: tuple[str, ...],
    seed: int,
    *,
    duration_s: float = 180.0,
    rate_hz: float = 10.0,
    signal: str | None = None,
    absent: tuple[str, ...] | None = None,
) -> Case:
    """Build a case hiding ``hidden`` effects (may be empty: a null case).

    Parameters
    ----------
    hidden : tuple of str
        Effect names to hide (keys of ``PLAUSIBLE``).
    seed : int
        Seed of the hidden values, the unit, the noise and the multilevel command.
    duration_s, rate_hz : float
        Trace length (s) and sample rate (Hz).
    signal : str or None
        One of ``SIGNALS``; None: the one ``EXCITING`` gives the first hidden effect listed
        there, else ``multilevel``.
    absent : tuple of str or None
        Effects removed from both the truth and the model; None: ``ABSENT`` of the hidden
        effects (minus hidden ones).
    """
    if absent is None:
        absent = tuple(
            dict.fromkeys(a for n in hidden for a in ABSENT.get(n, ()) if a not in hidden)
        )
    base, _ = start_config(load_config("t100"), absent)
    rng = np.random.default_rng([seed, 0xCA5E])
    truth = base
    for name in hidden:
        if name not in PLAUSIBLE:
            raise ValueError(f"unknown effect {name!r}; expected one of {', '.join(PLAUSIBLE)}")
        attr, lo, hi = PLAUSIBLE[name]
        truth = set_effect(truth, make_effect(name, {attr: float(rng.uniform(lo, hi))}))
    if signal is None:
        signal = next((EXCITING[n] for n in hidden if n in EXCITING), "multilevel")
    t, command = case_signal(signal, duration_s, rate_hz, seed)
    trace = simulate(truth, t, command, seed=seed)
    # The unit depends on the seed alone (perturb_unit), not on the measurement model.
    clean = simulate(replace(truth, measurement=Measurement()), t, command, seed=seed)
    unit = perturb_unit(truth, seed)
    start, _ = start_config(base, hidden)
    values = {}
    for name in hidden:
        effect = unit.effect(name)
        if effect is None:
            raise ValueError(f"hidden effect {name!r} missing from the simulated unit")
        values[name] = effect.params()
    return Case(trace=trace, start=start, hidden=values, signal=signal, clean=clean)
