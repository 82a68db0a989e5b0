"""Severity sweep and effectiveness estimate without ROS: the fault ladder, the estimate against
the simulator's true thrust on unseen units, change detection, health snapshots, the study."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.core.diagnosis.effectiveness import NO_EVIDENCE, EffectivenessEstimator
from thruster_fdd.core.diagnosis.health import HealthTracker, masks
from thruster_fdd.core.diagnosis.reference import ThrustReference
from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator, simulate
from thruster_fdd_shore.core.sim.plant import CONDITION_SPECS, severity_spec
from thruster_fdd_shore.core.sim.signals import make_signal

T100 = load_config("t100")


@pytest.fixture(scope="module")
def reference() -> ThrustReference:
    """The exported t100 reference the health node reads by default."""
    return ThrustReference.load(default_models_dir() / "reference")


def test_severity_ladder_passes_through_the_classes() -> None:
    for family, severity, condition in (
        ("blades", 1.0, "broken_blade_1"),
        ("blades", 2.0, "broken_blade_2"),
        ("fouling", 1.0, "biofouling"),
    ):
        assert severity_spec(family, severity) == CONDITION_SPECS[condition]
    assert severity_spec("blades", 0.0) == CONDITION_SPECS["nominal_15v"]
    half = severity_spec("blades", 0.5)
    assert CONDITION_SPECS["broken_blade_1"].k_thrust_factor < half.k_thrust_factor < 1.0
    heavy = severity_spec("fouling", 1.5)
    assert heavy.k_q_factor > CONDITION_SPECS["biofouling"].k_q_factor
    for bad in (("blades", -0.1), ("blades", 2.5), ("rust", 1.0), ("fouling", math.nan)):
        with pytest.raises(ValueError, match=r"severity|family"):
            severity_spec(*bad)


def test_a_spec_runs_in_the_simulator_as_its_class_does() -> None:
    t, command = make_signal("steps", 30.0, 10.0)
    by_name = simulate(T100, t, command, "broken_blade_1", seed=3)
    by_spec = simulate(
        T100, t, command, "broken_blade_1", seed=3, spec=severity_spec("blades", 1.0)
    )
    np.testing.assert_array_equal(by_name.rpm, by_spec.rpm)

    def steady_rpm(blades: float) -> float:
        sim = ThrusterSimulator(T100, seed=3)
        sim.set_condition("broken_blade_1", severity_spec("blades", blades))
        assert sim.condition == "broken_blade_1"
        return float(np.mean([sim.step(0.6, 0.1).rpm for _ in range(150)][-50:]))

    # A lighter load spins faster: healthy < half a blade < one blade.
    assert steady_rpm(0.0) < steady_rpm(0.5) < steady_rpm(1.0)


def _run(
    reference: ThrustReference, spec, seed: int, onset_s: float = 0.0, duration: float = 240.0
):
    """Stream a unit (healthy before ``onset_s``) through the estimator; (t, truth, estimates)
    every 5 s from 60 s after the onset, the truth against the unit's healthy twin over the
    estimator's window."""
    t, command = make_signal("multilevel", duration, 10.0, seed=seed)
    healthy = simulate(T100, t, command, seed=seed)
    sim = ThrusterSimulator(T100, seed=seed)
    est = EffectivenessEstimator(reference)
    out, previous, thrust = [], t[0], []
    for i, (ti, ci) in enumerate(zip(t.tolist(), command.tolist(), strict=True)):
        if ti >= onset_s and sim.condition == "nominal_15v" and spec is not None:
            sim.set_condition("broken_blade_1", spec)
        s = sim.step(ci, ti - previous)
        previous = ti
        thrust.append(s.thrust)
        est.push(s.t, s.command, s.voltage, s.rpm, s.current)
        if ti >= onset_s + 60.0 and i % 50 == 0:
            window = slice(max(0, i + 1 - 300), i + 1)
            t_f, t_h = np.array(thrust[window]), healthy.extra["thrust"][window]
            if t_h @ t_h > (0.05 * np.abs(healthy.extra["thrust"]).max()) ** 2 * len(t_h):
                out.append((ti, float(t_f @ t_h / (t_h @ t_h)), est.estimate()))
    return out


@pytest.mark.parametrize(
    ("family", "severity"),
    [("blades", 0.0), ("blades", 0.5), ("blades", 2.0), ("fouling", 0.5), ("fouling", 1.5)],
)
def test_effectiveness_against_true_thrust_on_unseen_units(
    reference: ThrustReference, family: str, severity: float
) -> None:
    """On units never used to tune the estimator (9001-9002), the effectiveness is within its
    target of the simulator's true thrust (the full study: scripts/effectiveness_study.py)."""
    spec = severity_spec(family, severity) if severity else None
    errors, inside = [], []
    for seed in (9001, 9002):
        for _, truth, e in _run(reference, spec, seed):
            errors.append(e.value - truth)
            inside.append(abs(e.value - truth) <= 2 * e.std)
    errors = np.abs(errors)
    assert len(errors) >= 40
    assert np.median(errors) <= 0.05
    assert np.percentile(errors, 95) <= 0.10
    assert np.mean(inside) >= 0.8, "the uncertainty covers the error"


def test_a_fault_mid_run_is_followed_and_idle_keeps_the_estimate(
    reference: ThrustReference,
) -> None:
    rows = _run(reference, severity_spec("blades", 2.0), 9003, onset_s=100.0, duration=300.0)
    late = [abs(e.value - truth) for t, truth, e in rows if t >= 190.0]
    assert late
    assert max(late) <= 0.1, "settled within 90 s of the onset"
    est = EffectivenessEstimator(reference)
    assert est.estimate() == NO_EVIDENCE
    for i in range(300):  # turning at 0.6
        est.push(0.1 * i, 0.6, 15.0, 2600.0, 3.0)
    before = est.estimate()
    for i in range(300, 900):  # idle: no evidence, the estimate stays
        est.push(0.1 * i, 0.0, 15.0, 0.0, 0.05)
    assert est.estimate().severity == pytest.approx(before.severity)
    assert est.estimate().family == before.family


def test_a_supply_outside_the_reference_uses_its_nearest_bin(reference: ThrustReference) -> None:
    low, high = float(reference.voltages[0]), float(reference.voltages[-1])
    assert reference.covers(15.0)
    assert not reference.covers(low - 1.0)
    assert not reference.covers(high + 1.0)
    assert reference.voltage_bin(low - 5.0) == 0
    assert reference.voltage_bin(high + 5.0) == len(reference.voltages) - 1
    assert reference.voltage_bin(15.1) == reference.voltage_bin(14.9)


def test_health_snapshots_flags_and_masks(reference: ThrustReference) -> None:
    tracker = HealthTracker(["a", "b", "c"], reference, stale_after_s=3.0)
    assert tracker.changed(0.0)
    assert not tracker.changed(0.5)
    tracker.add_diagnosis("a", "biofouling", 0.9, 1.0)
    tracker.add_diagnosis("b", "nominal_13v", 0.8, 1.0)
    assert tracker.changed(1.0)
    entries = tracker.snapshot(2.0)
    assert [e.condition for e in entries] == [6, 2, 0]
    assert [e.faulty for e in entries] == [True, False, False]
    assert masks(entries) == (0b001, 0b100)
    entries = tracker.snapshot(10.0)  # both silent since 1.0 s
    assert masks(entries) == (0, 0b111)
    assert all(e.label == "unknown" for e in entries)
    with pytest.raises(ValueError, match="distinct"):
        HealthTracker(["a", "a"], reference, 3.0)


def test_the_study_script_runs_and_writes_its_table(load_script, tmp_path: Path) -> None:
    study = load_script("effectiveness_study")
    study.main(
        ["--seeds", "1", "--first-seed", "9100", "--duration", "150", "--out", str(tmp_path)]
    )
    doc = json.loads((tmp_path / "runs.json").read_text())
    assert "half_blade" in doc["summary"]
    assert doc["summary"]["all sweep faults"]["n"] > 0
    assert (tmp_path / "table.md").read_text().startswith("| case |")
