"""Tests of the thruster physics simulator (core.sim.physics, core.sim.effects, core.sim.config)."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

from thruster_fdd.core.labels import CLASS_NAMES
from thruster_fdd_shore.core.sim import physics
from thruster_fdd_shore.core.sim.config import (
    Measurement,
    SimConfig,
    Structure,
    add_effect,
    dump_config,
    load_config,
    perturb_unit,
    preset_names,
    remove_effect,
    replace_effect,
    set_effect,
)
from thruster_fdd_shore.core.sim.effects import EFFECTS, CurrentLimit, Deadband, EscLag, make_effect
from thruster_fdd_shore.core.sim.metrics import StepMetrics, hysteresis_loop_area, step_metrics
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator, simulate
from thruster_fdd_shore.core.sim.plant import CONDITION_SPECS
from thruster_fdd_shore.core.sim.signals import make_signal
from thruster_fdd_shore.core.sim.steady import steady_state

REPO = Path(__file__).resolve().parents[3]
T200_DATA = REPO.parent / "shared" / "data" / "t200"


def clean(name: str) -> SimConfig:
    """Preset without noise and spread (for measuring the model's own behaviour)."""
    return dataclasses.replace(load_config(name), measurement=Measurement(), spread=0.0)


@pytest.fixture(scope="module")
def t100_steps() -> list[StepMetrics]:
    t, u = make_signal("steps", 160.0, 100.0)
    trace = simulate(clean("t100"), t, u)
    return step_metrics(trace.t, trace.command, trace.rpm)


def test_t100_dead_time_matches_paper(t100_steps: list[StepMetrics]) -> None:
    dead = [m.dead_time_s for m in t100_steps]
    assert len(dead) >= 14
    assert abs(np.median(dead) - 0.59) <= 0.05
    assert max(abs(d - 0.59) for d in dead) <= 0.1


def test_t100_settling_time_matches_paper(t100_steps: list[StepMetrics]) -> None:
    settle = [m.settling_time_s for m in t100_steps]
    assert abs(np.median(settle) - 2.95) <= 0.3
    assert max(abs(s - 2.95) for s in settle) <= 0.6


def test_t100_step_response_is_overdamped(t100_steps: list[StepMetrics]) -> None:
    assert max(m.overshoot for m in t100_steps) < 0.01


def test_t100_rpm_range_and_deadband() -> None:
    config = load_config("t100")
    u = np.linspace(-1.0, 1.0, 1601)
    for volts in (15.0, 16.0):
        rpm, _ = steady_state(config, u, volts, reported=True)
        nonzero = np.abs(rpm[rpm != 0.0])
        assert 300.0 <= nonzero.min() <= 600.0
        assert 3800.0 <= nonzero.max() <= 4500.0
    rpm16, _ = steady_state(config, u, 16.0)
    assert abs(np.abs(rpm16).max() - 4200.0) < 200.0
    assert np.all(rpm16[np.abs(u) <= 0.0625] == 0.0)
    assert np.all(rpm16[np.abs(u) >= 0.07] != 0.0)
    assert config.effect("deadband") == Deadband(width=0.0625)


def test_t100_current_grows_quadratically() -> None:
    u = np.linspace(0.25, 1.0, 31)
    _, current = steady_state(load_config("t100"), u, 15.0)
    lin = np.polyfit(u, current, 1, full=True)[1][0]
    quad_coef, quad_res = np.polyfit(u, current, 2, full=True)[:2]
    assert quad_coef[0] > 0
    assert quad_res[0] < 0.05 * lin
    assert np.all(np.diff(current) > 0)


def test_t100_hysteresis_grows_with_frequency() -> None:
    config = clean("t100")
    areas = []
    for freq in (0.01, 0.02, 0.03, 0.04):
        t, u = make_signal(f"sine:{freq}", 2.0 / freq, 20.0)
        trace = simulate(config, t, u)
        half = len(t) // 2
        areas.append(hysteresis_loop_area(trace.command[half:], trace.rpm[half:], 4000.0))
    assert all(b > a * 1.3 for a, b in itertools.pairwise(areas)), areas


def test_steady_state_matches_long_simulation() -> None:
    config = clean("t100")
    for name, volts in (("t100", 15.0), ("t200", 16.0)):
        config = clean(name)
        commands = [-1.0, -0.4, 0.2, 0.6, 1.0]
        rpm_ss, cur_ss = steady_state(config, np.array(commands), volts)
        for c, r, i in zip(commands, rpm_ss, cur_ss, strict=False):
            trace = simulate(config, np.arange(200) / 10.0, np.full(200, c), voltage=volts)
            assert abs(trace.rpm[-1] - r) < 0.005 * abs(r) + 1.0
            assert abs(trace.current[-1] - i) < 0.005 * abs(i) + 0.01


def test_current_limit_and_voltage_sag() -> None:
    config = set_effect(clean("t100"), CurrentLimit(i_max_a=5.0))
    trace = simulate(config, np.arange(100) / 10.0, np.full(100, 1.0), voltage=16.0)
    assert trace.current.max() <= 5.0 + 1e-9
    assert abs(trace.current[-1] - 5.0) < 1e-6
    assert trace.voltage[-1] == pytest.approx(16.0 - 0.03 * 5.0)
    _, cur = steady_state(config, np.array([1.0]), 16.0)
    assert cur[0] == pytest.approx(5.0, abs=1e-3)


def test_dead_time_effect_can_be_removed() -> None:
    config = remove_effect(clean("t100"), "dead_time")
    t, u = make_signal("steps", 30.0, 100.0)
    trace = simulate(config, t, u)
    assert max(m.dead_time_s for m in step_metrics(trace.t, trace.command, trace.rpm)) < 0.1


def test_coulomb_friction_stops_rotor_without_chatter() -> None:
    config = clean("t100")
    n = 300
    command = np.where(np.arange(n) < 100, 0.5, 0.0)
    trace = simulate(config, np.arange(n) / 10.0, command)
    assert trace.rpm[90] > 1000
    assert np.all(trace.rpm[-100:] == 0.0)


def test_integration_is_accurate_at_10_hz(monkeypatch: pytest.MonkeyPatch) -> None:
    config = clean("t100")
    t10, c10 = make_signal("multilevel", 120.0, 10.0, seed=4)
    slow = simulate(config, t10, c10)
    # The same held commands sampled at 100 Hz: command c10[i] holds over (t10[i-1], t10[i]].
    k = np.arange(10 * (len(t10) - 1) + 1)
    fast = simulate(config, k / 100.0, c10[np.ceil(k / 10).astype(int)])
    assert np.max(np.abs(fast.rpm[::10] - slow.rpm)) < 0.005 * 4200
    monkeypatch.setattr(physics, "MAX_SUBSTEP_S", 0.0005)
    fine = simulate(config, t10, c10)
    assert np.max(np.abs(fine.rpm - slow.rpm)) < 0.01 * 4200
    assert np.max(np.abs(fine.current - slow.current)) < 0.01 * 14.0


def test_streaming_equals_batch() -> None:
    config = load_config("t200")
    t, u = make_signal("mission", 60.0, 10.0, seed=2)
    trace = simulate(config, t, u, "broken_blade_1", seed=7)
    sim = ThrusterSimulator(config, "broken_blade_1", seed=7)
    dts = np.diff(t, prepend=t[0])
    rows = [sim.step(float(c), float(dt)) for c, dt in zip(u, dts, strict=False)]
    assert np.array_equal([s.rpm for s in rows], trace.rpm)
    assert np.array_equal([s.current for s in rows], trace.current)
    assert np.array_equal([s.voltage for s in rows], trace.voltage)
    sim.reset()
    again = [sim.step(float(c), float(dt)) for c, dt in zip(u, dts, strict=False)]
    assert again == rows


def test_seed_determinism_and_noise() -> None:
    config = load_config("t100")
    t, u = make_signal("multilevel", 100.0, 10.0, seed=1)
    a, b, c = (simulate(config, t, u, seed=s) for s in (5, 5, 6))
    assert np.array_equal(a.rpm, b.rpm)
    assert np.array_equal(a.current, b.current)
    assert not np.array_equal(a.rpm, c.rpm)


def test_measurement_quantisation_floor_and_outliers() -> None:
    m = Measurement(
        rpm_noise=5.0, rpm_step=10.0, current_step_a=0.1, outlier_prob=0.05, outlier_rpm=1000.0,
        rpm_floor=300.0, floor_zeroes_current=True,
    )  # fmt: skip
    config = dataclasses.replace(clean("t100"), measurement=m)
    n = 4000
    trace = simulate(config, np.arange(n) / 10.0, np.full(n, 0.5))
    assert np.allclose(trace.rpm / 10.0, np.round(trace.rpm / 10.0))
    assert np.allclose(trace.current / 0.1, np.round(trace.current / 0.1))
    settled = trace.rpm[100:]
    spikes = np.abs(settled - np.median(settled)) > 500.0
    assert 0.02 < spikes.mean() < 0.08
    config = dataclasses.replace(config, measurement=dataclasses.replace(m, outlier_prob=0.0))
    slow = simulate(config, np.arange(50) / 10.0, np.full(50, 0.07))
    assert np.all(slow.rpm[-10:] == 0.0)
    assert np.all(slow.current[-10:] == 0.0)


def test_conditions_move_in_designed_directions() -> None:
    config = dataclasses.replace(load_config("t100"), spread=0.0)
    n = 600
    result = {}
    for cond in CLASS_NAMES:
        tr = simulate(config, np.arange(n) / 10.0, np.full(n, 0.6), cond, seed=1)
        result[cond] = (tr.rpm[-300:].mean(), tr.current[-300:].mean(), tr.current[-300:].std())
    rpm0, cur0, std0 = result["nominal_15v"]
    assert result["nominal_13v"][0] < rpm0
    assert result["nominal_11v8"][0] < result["nominal_13v"][0]
    assert rpm0 < result["broken_blade_1"][0] < result["broken_blade_2"][0]
    assert cur0 > result["broken_blade_1"][1] > result["broken_blade_2"][1]
    assert std0 * 2 < result["broken_blade_1"][2] < result["broken_blade_2"][2]
    assert result["biofouling"][0] < 0.95 * rpm0
    assert result["biofouling"][1] > 1.1 * cur0
    thrust = {
        c: simulate(config, np.arange(n) / 10.0, np.full(n, 0.6), c).extra["thrust"][-1]
        for c in ("nominal_15v", "broken_blade_1", "biofouling")
    }
    assert thrust["broken_blade_1"] < thrust["nominal_15v"]
    assert thrust["biofouling"] < thrust["nominal_15v"]


def test_set_condition_keeps_state() -> None:
    sim = ThrusterSimulator(clean("t100"), "nominal_15v")
    for _ in range(200):
        before = sim.step(0.6, 0.1)
    sim.set_condition("biofouling")
    after = sim.step(0.6, 0.001)
    assert abs(after.rpm - before.rpm) < 20.0
    for _ in range(200):
        late = sim.step(0.6, 0.1)
    assert late.rpm < before.rpm - 100.0
    assert sim.condition == "biofouling"


def test_reverse_thrust_less_than_forward() -> None:
    config = clean("t100")
    fwd = simulate(config, np.arange(100) / 10.0, np.full(100, 1.0)).extra["thrust"][-1]
    rev = simulate(config, np.arange(100) / 10.0, np.full(100, -1.0)).extra["thrust"][-1]
    assert 0 < -rev < fwd


def test_temperature_rises_with_load() -> None:
    trace = simulate(clean("t100"), np.arange(3000) / 10.0, np.full(3000, 1.0))
    temp = trace.extra["temperature"]
    assert temp[0] == pytest.approx(15.0)
    assert temp[-1] > temp[100] > 15.5


def test_spread_draws_distinct_units() -> None:
    config = load_config("t100")
    a, b, a2 = perturb_unit(config, 1), perturb_unit(config, 2), perturb_unit(config, 1)
    assert a == a2
    assert a != b
    ratio = a.params.k_q / config.params.k_q
    assert ratio != 1.0
    assert abs(ratio - 1.0) < 0.1
    assert a.effect("esc_lag") != config.effect("esc_lag")
    nominal = dataclasses.replace(config, spread=0.0)
    assert perturb_unit(nominal, 1) == nominal


def test_config_round_trip(tmp_path: Path) -> None:
    assert set(preset_names()) == {"t100", "t200"}
    for name in preset_names():
        config = load_config(name)
        dump_config(config, tmp_path / f"{name}.yaml")
        assert load_config(tmp_path / f"{name}.yaml") == config
    changed = add_effect(remove_effect(load_config("t200"), "esc_lag"), EscLag(tau_s=0.3))
    dump_config(changed, tmp_path / "x.yaml")
    assert load_config(tmp_path / "x.yaml") == changed


def test_structure_round_trip_and_checks(tmp_path: Path) -> None:
    """``structure`` loads from YAML, round-trips, is left out of a dump at its defaults and
    refuses unknown keys and bad values."""
    structure = Structure(esc_tau2_s=0.1, i_idle_per_krpm_a=0.05, regen=False)
    config = dataclasses.replace(load_config("t100"), structure=structure)
    dump_config(config, tmp_path / "s.yaml")
    assert load_config(tmp_path / "s.yaml") == config
    assert "structure" in (tmp_path / "s.yaml").read_text()
    dump_config(load_config("t100"), tmp_path / "t.yaml")
    assert "structure" not in (tmp_path / "t.yaml").read_text()
    text = (tmp_path / "s.yaml").read_text()
    (tmp_path / "bad.yaml").write_text(text.replace("regen: false", "regen: maybe"))
    with pytest.raises(ValueError, match="regen"):
        load_config(tmp_path / "bad.yaml")
    (tmp_path / "bad.yaml").write_text(text.replace("regen: false", "esc_order: 2"))
    with pytest.raises(ValueError, match="esc_order"):
        load_config(tmp_path / "bad.yaml")
    with pytest.raises(ValueError, match=">= 0"):
        Structure(esc_tau2_s=-0.1)


def test_second_esc_stage_slows_the_start_not_the_end() -> None:
    base = remove_effect(clean("t100"), "dead_time")
    second = dataclasses.replace(base, structure=Structure(esc_tau2_s=0.3))
    t = np.arange(100) / 10.0
    one, two = (simulate(c, t, np.full(100, 0.6)) for c in (base, second))
    assert two.rpm[3] < 0.6 * one.rpm[3]  # 0.3 s after the step
    assert two.rpm[-1] == pytest.approx(one.rpm[-1], rel=1e-3)


def test_idle_current_grows_with_speed() -> None:
    base = remove_effect(clean("t100"), "voltage_sag")  # a sag would couple current to speed
    lossy = dataclasses.replace(base, structure=Structure(i_idle_per_krpm_a=0.2))
    u = np.array([0.0, 0.5, 1.0])
    rpm0, cur0 = steady_state(base, u, 15.0)
    rpm1, cur1 = steady_state(lossy, u, 15.0)
    np.testing.assert_allclose(rpm1, rpm0)
    np.testing.assert_allclose(cur1 - cur0, 0.2 * np.abs(rpm0) / 1000.0, rtol=1e-9)
    trace = simulate(lossy, np.arange(200) / 10.0, np.full(200, 1.0))
    assert trace.current[-1] == pytest.approx(cur1[2], rel=5e-3)


def test_without_regeneration_the_rotor_coasts() -> None:
    """Regenerative (reference): a fast command drop brakes the rotor under drive and pushes
    current back to the bus. Without it the bus current stays at idle and the rotor coasts
    down on its propeller load, more slowly."""
    base = remove_effect(remove_effect(clean("t100"), "dead_time"), "esc_lag")
    base = set_effect(base, make_effect("esc_lag", {"tau_s": 0.05}))
    coast = dataclasses.replace(base, structure=Structure(regen=False))
    t = np.arange(120) / 20.0
    u = np.where(t < 3.0, 1.0, 0.3)
    regen, free = (simulate(c, t, u) for c in (base, coast))
    after = t > 3.0
    assert regen.current[after].min() < -0.2
    assert free.current[after].min() >= base.params.i_idle_a - 1e-12
    k = int(np.argmax(t >= 3.2))
    assert free.rpm[k] > regen.rpm[k] + 100.0
    assert free.rpm[-1] == pytest.approx(regen.rpm[-1], rel=1e-3)


def test_effect_registry_and_helpers() -> None:
    assert list(EFFECTS) == [
        "dead_time", "deadband", "esc_lag", "slew_rate_limit", "coulomb_friction",
        "viscous_friction", "voltage_sag", "current_limit",
    ]  # fmt: skip
    config = load_config("t100")
    assert make_effect("slew_rate_limit", {"rate_per_s": 2.0}).params() == {"rate_per_s": 2.0}
    with_slew = add_effect(config, make_effect("slew_rate_limit", {"rate_per_s": 2.0}))
    assert with_slew.effect_names.index("slew_rate_limit") == 3
    assert replace_effect(config, EscLag(tau_s=1.0)).effect("esc_lag") == EscLag(tau_s=1.0)
    assert "dead_time" not in remove_effect(config, "dead_time").effect_names
    with pytest.raises(ValueError, match="already present"):
        add_effect(config, EscLag(tau_s=1.0))
    with pytest.raises(ValueError, match="not present"):
        remove_effect(remove_effect(config, "esc_lag"), "esc_lag")
    with pytest.raises(ValueError, match="unknown effect"):
        make_effect("backlash", {})
    with pytest.raises(ValueError, match="missing"):
        make_effect("esc_lag", {"tau": 1.0})
    with pytest.raises(ValueError, match="> 0"):
        EscLag(tau_s=0.0)
    with pytest.raises(ValueError, match="< 1"):
        Deadband(width=1.0)


def test_slew_rate_limit_slows_response() -> None:
    config = set_effect(
        remove_effect(clean("t100"), "esc_lag"), make_effect("slew_rate_limit", {"rate_per_s": 0.5})
    )
    trace = simulate(config, np.arange(60) / 10.0, np.full(60, 1.0))
    # Duty ramps at 0.5/s after the 0.55 s dead time: still below full speed at 2 s.
    rpm_full, _ = steady_state(config, np.array([1.0]), 15.0)
    assert trace.rpm[20] < 0.8 * rpm_full[0]
    assert trace.rpm[-1] == pytest.approx(rpm_full[0], rel=0.01)


def test_bad_inputs_raise() -> None:
    config = load_config("t100")
    with pytest.raises(ValueError, match="unknown condition"):
        ThrusterSimulator(config, "broken_blade_3")
    with pytest.raises(ValueError, match="supply voltage"):
        ThrusterSimulator(config, voltage=-1.0)
    with pytest.raises(ValueError, match="dt"):
        ThrusterSimulator(config).step(0.5, -0.1)
    with pytest.raises(ValueError, match="strictly increasing"):
        simulate(config, np.array([0.0, 0.0]), np.zeros(2))
    with pytest.raises(ValueError, match="neither a preset"):
        load_config("t300")
    with pytest.raises(ValueError, match="unknown condition"):
        steady_state(config, np.zeros(3), 15.0, condition="rusty")
    assert set(CONDITION_SPECS) == set(CLASS_NAMES)


@pytest.mark.skipif(not T200_DATA.is_dir(), reason=f"T200 measurements not found at {T200_DATA}")
def test_t200_preset_fits_measurements(load_script) -> None:
    cal = load_script("calibrate_t200")
    config = load_config("t200")
    sheets = cal.load_sheets(T200_DATA)
    assert [s.voltage for s in sheets] == [10.0, 12.0, 14.0, 16.0, 18.0, 20.0]
    for sheet in sheets:
        err = cal.sheet_errors(config, sheet)
        assert err.rpm_median < 3.0, err
        assert err.current_median < 3.0, err
        assert err.band_error_us <= 8.0, err
