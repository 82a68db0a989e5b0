"""Synthetic measured traces with hidden effects, for tests, the study and the benchmark.

A case hides effects from the model: the "measured" trace is simulated (with unit spread,
noise, quantisation and outliers) from the t100 preset with the hidden effects set to random
plausible values; the model starts from the t100 preset without them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thruster_fdd.core.data import Trace
from thruster_fdd.core.discrepancy import start_config
from thruster_fdd.core.effects import make_effect
from thruster_fdd.core.physics import simulate
from thruster_fdd.core.signals import make_signal
from thruster_fdd.core.simconfig import SimConfig, load_config, perturb_unit, set_effect

PLAUSIBLE: dict[str, tuple[str, float, float]] = {
    "dead_time": ("delay_s", 0.3, 1.0),
    "deadband": ("width", 0.04, 0.12),
    "esc_lag": ("tau_s", 0.3, 1.0),
    "slew_rate_limit": ("rate_per_s", 0.5, 2.0),
    "coulomb_friction": ("torque_nm", 0.003, 0.008),
    "viscous_friction": ("coeff", 2e-5, 6e-5),
    "voltage_sag": ("r_internal_ohm", 0.1, 0.3),
    "current_limit": ("i_max_a", 6.0, 9.0),
}
"""Effect -> (parameter, low, high): uniform range of the hidden value for the t100 preset."""


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
    """

    trace: Trace
    start: SimConfig
    hidden: dict[str, dict[str, float]]


def make_case(
    hidden: tuple[str, ...], seed: int, *, duration_s: float = 180.0, rate_hz: float = 10.0
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
    """
    base = load_config("t100")
    rng = np.random.default_rng([seed, 0xCA5E])
    truth = base
    for name in hidden:
        if name not in PLAUSIBLE:
            raise ValueError(f"unknown effect {name!r}; expected one of {', '.join(PLAUSIBLE)}")
        attr, lo, hi = PLAUSIBLE[name]
        truth = set_effect(truth, make_effect(name, {attr: float(rng.uniform(lo, hi))}))
    t, command = make_signal("multilevel", duration_s, rate_hz, seed=seed)
    trace = simulate(truth, t, command, seed=seed)
    unit = perturb_unit(truth, seed)
    start, _ = start_config(base, hidden)
    values = {}
    for name in hidden:
        effect = unit.effect(name)
        if effect is None:
            raise ValueError(f"hidden effect {name!r} missing from the simulated unit")
        values[name] = effect.params()
    return Case(trace=trace, start=start, hidden=values)
