"""Tests of the command signals (core.sim.signals)."""

from __future__ import annotations

import numpy as np
import pytest

from thruster_fdd_shore.core.sim.signals import STEP_HOLD_S, make_signal


@pytest.mark.parametrize("spec", ["steps", "sine:0.02", "chirp", "multilevel", "mission"])
def test_shapes_and_range(spec: str) -> None:
    t, u = make_signal(spec, 300.0, 10.0, seed=3)
    assert t.shape == u.shape == (3000,)
    assert t[0] == 0.0
    assert np.allclose(np.diff(t), 0.1)
    assert np.all(np.abs(u) <= 1.0)
    assert np.ptp(u) > 0.5


def test_steps_are_the_papers_quarter_steps() -> None:
    t, u = make_signal("steps", 170.0, 10.0)
    assert np.allclose(u / 0.25, np.round(u / 0.25))
    assert set(np.round(u, 2)) == {-1.0, -0.75, -0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0}
    changes = np.flatnonzero(np.diff(u)) + 1
    assert np.all(np.abs(np.diff(u)[changes - 1]) == 0.25)
    assert np.all(np.diff(t[changes]) >= STEP_HOLD_S - 1e-9)
    assert STEP_HOLD_S >= 3 * 2.95


def test_sine_frequency_and_amplitude() -> None:
    t, u = make_signal("sine:0.04", 100.0, 20.0)
    crossings = np.flatnonzero(np.diff(np.sign(u)) > 0)
    assert len(crossings) == 4  # the first is the start at sin(0) = 0
    assert np.diff(t[crossings]).mean() == pytest.approx(25.0, abs=0.1)
    assert u.max() == pytest.approx(1.0, abs=1e-3)


def test_chirp_sweeps_up() -> None:
    t, u = make_signal("chirp", 600.0, 10.0)
    ups = t[np.flatnonzero(np.diff(np.sign(u)) > 0)]
    periods = np.diff(ups)
    assert periods[0] > 40.0
    assert periods[-1] < 12.0
    assert np.all(np.diff(periods) < 0)


def test_multilevel_is_seeded_and_piecewise_constant() -> None:
    _, a = make_signal("multilevel", 300.0, 10.0, seed=1)
    _, b = make_signal("multilevel", 300.0, 10.0, seed=1)
    _, c = make_signal("multilevel", 300.0, 10.0, seed=2)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    holds = np.diff(np.flatnonzero(np.diff(a)))
    assert holds.min() >= 19
    assert holds.max() <= 151
    assert len(np.unique(a)) >= 15


def test_mission_has_idle_transit_and_reversals() -> None:
    _, u = make_signal("mission", 3600.0, 10.0, seed=0)
    assert np.mean(u == 0.0) > 0.05
    assert np.mean(np.abs(u) > 0.4) > 0.1
    signs = np.sign(u[np.abs(u) > 0.25])
    assert np.sum(np.diff(signs) != 0) >= 3
    small = np.abs(u) < 0.3
    assert np.mean(small & (np.abs(np.diff(u, prepend=0.0)) > 0)) > 0.05


@pytest.mark.parametrize("spec", ["square", "sine", "sine:x", "sine:-1", "sine:6", "chirp:2", ""])
def test_bad_spec_names_accepted_forms(spec: str) -> None:
    with pytest.raises(ValueError, match="sine"):
        make_signal(spec, 10.0, 10.0)


@pytest.mark.parametrize(("duration", "rate"), [(0.0, 10.0), (10.0, 0.0), (-1.0, 10.0)])
def test_bad_duration_or_rate(duration: float, rate: float) -> None:
    with pytest.raises(ValueError, match="must be > 0"):
        make_signal("steps", duration, rate)
