"""The compiled free run (core.sim.freerun) equals the reference ThrusterSimulator."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from thruster_fdd_shore.core.sim.config import (
    Measurement,
    SimConfig,
    Structure,
    load_config,
    set_effect,
)
from thruster_fdd_shore.core.sim.effects import make_effect
from thruster_fdd_shore.core.sim.freerun import free_run
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator

RTOL = 1e-9
"""Relative tolerance of the comparison (the kernel differs from the reference by rounding)."""

RANGES: dict[str, tuple[str, float, float]] = {
    "dead_time": ("delay_s", 0.05, 1.2),
    "deadband": ("width", 0.01, 0.15),
    "esc_lag": ("tau_s", 0.05, 1.0),
    "slew_rate_limit": ("rate_per_s", 0.3, 5.0),
    "coulomb_friction": ("torque_nm", 1e-4, 0.02),
    "viscous_friction": ("coeff", 1e-6, 2.5e-4),
    "voltage_sag": ("r_internal_ohm", 0.01, 0.4),
    "current_limit": ("i_max_a", 3.0, 12.0),
}


def _random_config(rng: np.random.Generator, *, delayed_and_limited: bool) -> SimConfig:
    """t100 with every base parameter scaled, each effect and each structural switch on or off
    at random values."""
    base = load_config("t100")
    p = base.params
    params = replace(
        p,
        k_e=p.k_e * rng.uniform(0.7, 1.4),
        r_ohm=p.r_ohm * rng.uniform(0.7, 1.4),
        r_speed_ohm_s=float(rng.choice([0.0, rng.uniform(1e-4, 1e-3)])),
        esc_v_sat_v=float(rng.choice([math.inf, rng.uniform(40.0, 100.0)])),
        inertia=p.inertia * rng.uniform(0.5, 2.0),
        k_q=p.k_q * rng.uniform(0.7, 1.4),
        k_q_reverse_ratio=rng.uniform(0.7, 1.3),
        i_idle_a=p.i_idle_a * rng.uniform(0.0, 2.0),
    )
    config = SimConfig(name="random", params=params, measurement=Measurement(), spread=0.0)
    for name, (attr, lo, hi) in RANGES.items():
        forced = delayed_and_limited and name in ("dead_time", "current_limit")
        if forced or rng.random() < 0.5:
            value = rng.uniform(lo, hi)
            if forced and name == "current_limit":
                value = rng.uniform(3.0, 5.0)  # binds at |command| well under 1
            config = set_effect(config, make_effect(name, {attr: value}))
    # A child generator: the draws of the configuration and history above stay as they were.
    srng = rng.spawn(1)[0]
    structure = Structure(
        esc_tau2_s=float(srng.choice([0.0, srng.uniform(0.02, 0.4)])),
        i_idle_per_krpm_a=float(srng.choice([0.0, srng.uniform(0.02, 0.3)])),
        regen=bool(srng.random() < 0.5),
    )
    return replace(config, structure=structure)


def _random_history(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Irregular times (some repeated, some shorter than a substep, some long), commands
    (holds, ramps, jumps beyond +-1, noise) and a supply with a few steps; shapes (n,)."""
    kind = rng.choice(4, size=n, p=[0.7, 0.1, 0.1, 0.1])
    dt = np.choose(
        kind,
        [
            rng.uniform(0.05, 0.15, n),
            np.zeros(n),
            rng.uniform(1e-4, 9e-3, n),
            rng.uniform(0.3, 1.5, n),
        ],
    )
    t = rng.uniform(-5.0, 5.0) + np.cumsum(dt)
    knots = np.sort(rng.uniform(t[0], t[-1], 12))
    levels = rng.uniform(-1.2, 1.2, 12)
    ramp = np.interp(t, knots, levels)
    held = levels[np.clip(np.searchsorted(knots, t), 0, 11)]
    command = np.where(rng.random(n) < 0.5, ramp, held) + rng.normal(0.0, 0.02, n)
    supply = np.round(rng.uniform(11.0, 16.0) + np.cumsum(rng.random(n) < 0.02), 2)
    return t, command, supply


def _reference(
    config: SimConfig, t: np.ndarray, command: np.ndarray, supply: np.ndarray
) -> dict[str, np.ndarray]:
    """ThrusterSimulator stepped through the history (what discrepancy.simulate_model did)."""
    sim = ThrusterSimulator(config, voltage=float(supply[0]), seed=0)
    rows = []
    previous, level = t[0], supply[0]
    for ti, ci, vi in zip(t.tolist(), command.tolist(), supply.tolist(), strict=True):
        if vi != level:
            level = vi
            sim.set_voltage(vi)
        s = sim.step(ci, ti - previous)
        previous = ti
        rows.append((s.rpm, s.current, s.voltage))
    out = np.array(rows)
    return {"rpm": out[:, 0], "current": out[:, 1], "voltage": out[:, 2]}


def _assert_equal(got: dict[str, np.ndarray], want: dict[str, np.ndarray]) -> None:
    for name in ("rpm", "current", "voltage"):
        scale = float(np.max(np.abs(want[name])))
        np.testing.assert_allclose(
            got[name], want[name], rtol=RTOL, atol=RTOL * scale, err_msg=name
        )


@pytest.mark.parametrize("seed", range(24))
def test_free_run_equals_simulator(seed: int) -> None:
    """Random configurations (every effect on or off) and irregular random histories."""
    rng = np.random.default_rng([seed, 0xF4EE])
    delayed_and_limited = seed % 3 == 0
    config = _random_config(rng, delayed_and_limited=delayed_and_limited)
    t, command, supply = _random_history(rng, 400)
    want = _reference(config, t, command, supply)
    got = free_run(config, t, command, supply)
    _assert_equal(got, want)
    assert np.ptp(want["rpm"]) > 1000.0  # the thruster moved
    if delayed_and_limited:
        i_max = config.effect("current_limit").i_max_a
        assert np.sum(want["current"] == i_max) >= 5  # the limit binds


def test_free_run_sees_small_differences() -> None:
    """The comparison would fail if the kernel differed: a 1e-6 change of one parameter, of
    the dead time or of a structural value, or the other braking law, is far outside the
    tolerance."""
    rng = np.random.default_rng(7)
    config = _random_config(rng, delayed_and_limited=True)
    config = replace(config, structure=Structure(0.1, 0.1, regen=False))
    t, command, supply = _random_history(rng, 400)
    want = _reference(config, t, command, supply)
    delay = config.effect("dead_time").delay_s
    s = config.structure
    changed = (
        replace(config, params=replace(config.params, k_e=config.params.k_e * (1 + 1e-6))),
        set_effect(config, make_effect("dead_time", {"delay_s": delay * (1 + 1e-6)})),
        replace(config, structure=replace(s, esc_tau2_s=s.esc_tau2_s * (1 + 1e-6))),
        replace(config, structure=replace(s, i_idle_per_krpm_a=s.i_idle_per_krpm_a * (1 + 1e-6))),
        replace(config, structure=replace(s, regen=True)),
    )
    for other in changed:
        with pytest.raises(AssertionError):
            _assert_equal(free_run(other, t, command, supply), want)


def test_free_run_ignores_spread_and_measurement() -> None:
    """The nominal unit, noise-free: spread and measurement model do not enter."""
    rng = np.random.default_rng(3)
    config = _random_config(rng, delayed_and_limited=False)
    t, command, supply = _random_history(rng, 200)
    noisy = replace(config, spread=0.05, measurement=load_config("t100").measurement)
    _assert_equal(free_run(noisy, t, command, supply), free_run(config, t, command, supply))


def test_free_run_rejects_bad_input() -> None:
    config = load_config("t100")
    t = np.arange(10) * 0.1
    u = np.zeros(10)
    v = np.full(10, 15.0)
    with pytest.raises(ValueError, match="one non-zero length"):
        free_run(config, t, u[:5], v)
    with pytest.raises(ValueError, match="one non-zero length"):
        free_run(config, t[:0], u[:0], v[:0])
    with pytest.raises(ValueError, match="command must be finite"):
        free_run(config, t, np.where(t > 0.5, np.nan, u), v)
    with pytest.raises(ValueError, match="non-decreasing"):
        free_run(config, t[::-1], u, v)
    with pytest.raises(ValueError, match=r"supply voltage must be in \(0, 60\]"):
        free_run(config, t, u, np.zeros(10))
