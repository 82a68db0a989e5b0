"""Discrepancy workflow: the selection engine's rule, and properties over random units and seeds
(nothing named on null traces, hidden effects found with their values, outside-vocabulary
structure never named as an effect, answers independent of the fold assignment)."""

from __future__ import annotations

import contextlib
import functools
import io
import json
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from thruster_fdd_shore.cli import main
from thruster_fdd_shore.core.discrepancy.correction import basis, corrected
from thruster_fdd_shore.core.discrepancy.engine import (
    _contradicted,
    judge,
    run_workflow,
    structured,
)
from thruster_fdd_shore.core.discrepancy.measure import (
    FOLDS,
    N_BLOCKS,
    Measured,
    block_of,
    prepare_measured,
    with_held,
)
from thruster_fdd_shore.core.discrepancy.moves import Move, Spec
from thruster_fdd_shore.core.discrepancy.report import REPORT_FILES
from thruster_fdd_shore.core.discrepancy.score import (
    Policy,
    Scored,
    evaluate,
    evidence,
    excess,
    gain_of,
)
from thruster_fdd_shore.core.sim.cases import PLAUSIBLE, make_case
from thruster_fdd_shore.core.sim.config import load_config, perturb_unit, set_effect
from thruster_fdd_shore.core.sim.effects import make_effect
from thruster_fdd_shore.core.sim.physics import simulate
from thruster_fdd_shore.core.sim.signals import make_signal
from thruster_fdd_shore.core.traces.csv_io import read_trace_csv, write_trace_csv

REPO = Path(__file__).resolve().parents[3]
T200_DATA = REPO.parent / "shared" / "data" / "t200"

DURATION_S = 60.0
"""Trace length of the workflow runs here, s (the study, scripts/discrepancy_study.py, runs
longer traces and many more seeds)."""

ANY_SIGNAL = ("dead_time", "deadband", "esc_lag", "voltage_sag")
"""Effects the default ``multilevel`` command excites (``cases.EXCITING`` names the others)."""

EXAMPLES = settings(
    max_examples=3,
    deadline=None,
    derandomize=True,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=[HealthCheck.too_slow],
)
"""Each example is a whole workflow run (5-20 s): no shrinking, the failing example is shown."""


@functools.cache
def _null_data() -> Measured:
    """A prepared null trace (seed 3), the samples under the acceptance rule's synthetic
    residuals; prepared once, as every hypothesis example reads the same."""
    case = make_case((), 3, duration_s=DURATION_S)
    return prepare_measured(case.trace, case.start)


def _run(trace, start, **kw):
    result, _ = run_workflow(trace, start, workers=1, progress=False, **kw)
    return result


def _warp(u: np.ndarray, strength: float) -> np.ndarray:
    """A smooth monotone map of the command, as an ESC with another throttle curve applies it:
    structure neither the simulator nor the effect vocabulary has."""
    return np.clip(u + strength * u * (1.0 - np.abs(u)), -1.0, 1.0)


def warped_case(hidden: dict[str, float], seed: int, strength: float):
    """A t100 unit (spread by ``seed``) with the effects ``hidden`` (name -> value of its
    ``PLAUSIBLE`` parameter) whose ESC maps the command through ``_warp``; the trace records
    the command sent, and the start lacks the hidden effects."""
    t100 = load_config("t100")
    unit = t100
    for name, value in hidden.items():
        unit = set_effect(unit, make_effect(name, {PLAUSIBLE[name][0]: value}))
    unit = perturb_unit(unit, seed)
    t, u = make_signal("multilevel", DURATION_S, 10.0, seed=seed)
    trace = replace(simulate(unit, t, _warp(u, strength), seed=seed), command=u)
    start = replace(t100, effects=tuple(e for e in t100.effects if e.name not in hidden))
    return trace, start


def test_a_gain_is_evidence_only_above_its_uncertainty_and_the_least_gain() -> None:
    sv = np.array([[1.0] * 10, [0.1] * 10])  # gain 10, se 1
    assert evidence(sv, 2.0, 3.0)[2]
    assert not evidence(sv, 11.0, 3.0)[2]
    assert not evidence(sv, 2.0, 10.5)[2]
    assert not evidence(-sv * [[1.0], [-1.0]], 2.0, 0.0)[2]


@given(seed=st.integers(0, 2**31 - 1), gap=st.floats(0.3, 2.0))
@settings(max_examples=10, deadline=None)
def test_a_joint_move_is_taken_only_when_it_beats_each_part_alone(seed: int, gap: float) -> None:
    """A joint move that gains over the model is still refused when one of its parts made alone
    does as well: each part must earn its place beside the other."""
    data = _null_data()
    rng = np.random.default_rng(seed)
    noise = rng.normal(size=(3, len(data.t)))
    n = len(data.t)
    joint, parent = Scored(Spec(), (), noise, noise), Scored(Spec(), (), noise + gap, noise + gap)
    move = Move("joint", "coulomb_friction")
    for part_r, taken in ((noise + gap, True), (noise, False)):
        part = Scored(Spec(), (), part_r, part_r, np.ones(n, bool))
        j = judge(move, replace(joint, active=np.ones(n, bool)), parent, data,
                  np.ones(3), Policy(), 3, [part, part])  # fmt: skip
        assert j.significant
        assert j.accepted == taken


@given(seed=st.integers(0, 2**31 - 1), share=st.floats(0.05, 0.12))
@settings(max_examples=10, deadline=None)
def test_a_move_is_credited_with_the_re_fit_it_allows(seed: int, share: float) -> None:
    """A move that acts on a few samples (a current limit at the top of the reversals) and,
    made, lets the base fit everywhere else: most of its gain lies where it does not act, and
    it is taken once its gain where it acts is evidence. Without that, it is refused."""
    data = _null_data()
    rng = np.random.default_rng(seed)
    noise = rng.normal(size=(3, len(data.t)))
    active = rng.random(len(data.t)) < share
    move = Move("add", "current_limit")
    cand = Scored(Spec(), (), noise, noise, active)
    for where, taken in ((2.0, True), (0.0, False)):
        off = noise + np.where(active, where, 1.0)
        j = judge(move, cand, Scored(Spec(), (), off, off), data, np.ones(3), Policy(), 3)
        assert j.significant
        assert j.gain > 2.0 * j.where
        assert j.accepted == taken


@given(seed=st.integers(0, 2**31 - 1), i_max=st.floats(6.5, 7.5))
@EXAMPLES
def test_a_move_acts_on_held_out_samples_only_where_its_fold_saw_it_act(
    seed: int, i_max: float
) -> None:
    """A current limit that binds in one stretch of the trace only: the fold holding that
    stretch out fits the limit to samples that never show it, so whatever value it keeps
    there is no prediction, and the move acts nowhere. Shown in two stretches in different
    folds, each fold's fit sees it, and it acts in both."""
    t100 = load_config("t100")
    unit = perturb_unit(set_effect(t100, make_effect("current_limit", {"i_max_a": i_max})), seed)
    start = replace(t100, effects=tuple(e for e in t100.effects if e.name != "current_limit"))
    t = np.arange(600) / 10.0
    blocks = block_of(len(t))
    policy = Policy()
    for pulses in ((25.0,), (7.0, 25.0)):  # blocks 4, and 1 and 4: in different folds
        u = np.where((t // 2) % 2 == 0, 0.2, 0.4)
        for t0 in pulses:
            u[(t >= t0) & (t < t0 + 2.0)] = 1.0
        data = prepare_measured(simulate(unit, t, u, seed=seed), start)
        current = evaluate((None, None, data, start, policy, None))
        scored = evaluate((Move("add", "current_limit"), current, data, start, policy, None))
        pulsed = {int(blocks[np.searchsorted(t, t0)]) for t0 in pulses}
        acting = {int(b) for b in np.unique(blocks[scored.active])}
        assert acting == (pulsed if len(pulses) > 1 else set())


@given(seed=st.integers(0, 2**31 - 1), delta=st.floats(0.01, 3.0))
@settings(max_examples=20, deadline=None)
def test_the_gain_of_two_models_and_its_variance_follow_the_noise(seed: int, delta: float) -> None:
    """Identical residuals gain nothing with no uncertainty; residuals ``delta`` apart have
    the variance ``w * delta**2`` per sample, whatever the noise."""
    data = _null_data()
    rng = np.random.default_rng(seed)
    r = rng.normal(size=(3, len(data.t)))
    w = np.array([1.0, 0.5, 0.25])
    same = gain_of(r, r, data, w)
    np.testing.assert_array_equal(same, 0.0)
    sv = gain_of(r, r + delta, data, w)
    seen = (data.rpm != 0.0) if data.rpm_floor > 0.0 else np.ones(len(data.t), bool)
    expected = delta**2 * (w[0] * seen.sum() + (w[1] + w[2]) * len(data.t))
    assert sv[1].sum() == pytest.approx(expected, rel=1e-9)


@given(seed=st.integers(0, 2**31 - 1), loss=st.floats(0.3, 1.0))
@settings(max_examples=10, deadline=None)
def test_a_move_that_loses_once_both_are_corrected_is_refused(seed: int, loss: float) -> None:
    """A move whose plain gain is evidence but which is clearly worse than its parent once both
    have the generic correction stands in for a difference it does not model: refused; the
    same move that only ties there is taken (the correction explains as much: not behind)."""
    data = _null_data()
    rng = np.random.default_rng(seed)
    noise = rng.normal(size=(3, len(data.t)))
    n = len(data.t)
    parent = Scored(Spec(), (), noise + 1.0, noise)
    move = Move("add", "deadband")
    for cand_g, taken in ((noise + loss, False), (noise, True)):
        cand = Scored(Spec(), (), noise, cand_g, np.ones(n, bool))
        j = judge(move, cand, parent, data, np.ones(3), Policy(), 3)
        assert j.significant
        assert j.accepted == taken


@given(seed=st.integers(0, 2**31 - 1), share=st.floats(0.2, 0.5), size=st.floats(1.5, 4.0))
@settings(max_examples=20, deadline=None)
def test_the_rest_is_measured_where_asked(seed: int, share: float, size: float) -> None:
    """``excess`` over the samples ``where`` selects: an offset of ``size`` noise std confined
    to them shows there as ``1 + size**2`` noise variances and not elsewhere, where the noise
    alone gives about 1; no sample selected gives 0."""
    data = _null_data()
    rng = np.random.default_rng(seed)
    n = len(data.t)
    where = rng.random(n) < share
    r = rng.normal(size=(3, n)) + np.where(where, size, 0.0)
    scored = Scored(Spec(), (), r, r)
    assert excess(scored, data, Policy(), where) == pytest.approx(1.0 + size**2, rel=0.25)
    assert excess(scored, data, Policy(), ~where) == pytest.approx(1.0, rel=0.25)
    assert excess(scored, data, Policy(), np.zeros(n, bool)) == 0.0


@given(
    seed=st.integers(0, 2**31 - 1),
    dense=st.integers(0, N_BLOCKS - 1),
    sparse=st.integers(1, 8),
    size=st.floats(2.0, 4.0),
)
@settings(max_examples=20, deadline=None)
def test_a_region_rest_counts_every_sample_whatever_the_folds(
    seed: int, dense: int, sparse: int, size: float
) -> None:
    """A region whose samples sit mostly in one block, with ``sparse`` noise-only samples in
    every other block, shows its offset of ``size`` noise std: the blocks holding a handful of
    its samples do not outvote the block holding most."""
    data = _null_data()
    rng = np.random.default_rng(seed)
    n = len(data.t)
    blocks = block_of(n)
    where = blocks == dense
    for b in set(range(N_BLOCKS)) - {dense}:
        where[rng.choice(np.flatnonzero(blocks == b), sparse, replace=False)] = True
    r = rng.normal(size=(3, n)) + np.where(blocks == dense, size, 0.0)
    shares = where.sum(), (where & (blocks == dense)).sum()
    expected = 1.0 + size**2 * shares[1] / shares[0]
    assert excess(Scored(Spec(), (), r, r), data, Policy(), where) == pytest.approx(expected, 0.25)


def test_absence_is_shown_only_where_the_model_without_the_effect_fits() -> None:
    """A start deadband twice as wide as the unit's is contradicted by a model without it that
    fits where the band acts; a model without it that beats the claim there but still leaves
    structure (the thruster differs there in a way the model lacks) does not show absence."""
    case = make_case((), 3, duration_s=DURATION_S, signal="lowspeed")
    t100 = load_config("t100")
    width = 2.0 * t100.effect("deadband").params()["width"]
    anchor = set_effect(t100, make_effect("deadband", {"width": width}))
    data = prepare_measured(case.trace, anchor)
    policy = Policy()
    current = evaluate((None, None, data, anchor, policy, None))
    claim = evaluate((None, current, data, anchor, policy, "deadband"))
    assert claim.active.sum() > 50
    noise = np.random.default_rng(3).normal(size=claim.r.shape)
    fits = Scored(current.spec, current.folds, noise, noise)
    assert _contradicted(fits, current, "deadband", data, anchor, policy, 1)[0]
    rest = noise + np.where(claim.active, 3.0, 0.0)
    assert excess(Scored(current.spec, (), rest, rest), data, policy, claim.active) > 2.0
    leaves = Scored(current.spec, current.folds, rest, rest)
    assert gain_of(rest, claim.r, data, np.ones(3), claim.active)[0].sum() > 100.0
    assert not _contradicted(leaves, current, "deadband", data, anchor, policy, 1)[0]


def test_the_generic_correction_takes_a_smooth_curve_but_not_a_deadband() -> None:
    """Fitted on the training blocks of a fold, the static correction removes a residual that
    is a smooth function of the command from the held-out blocks, and leaves much of a
    deadband's sharp notch: the premise of the stand-in guard."""
    data = _null_data()
    ramp = np.resize(np.linspace(-1.0, 1.0, 41), len(data.t))  # every command in each block
    data = replace(data, command=ramp, rpm=4000.0 * ramp)
    rng = np.random.default_rng(0)
    noise = rng.normal(size=(3, len(data.t)))
    u = data.command
    seen = np.ones((3, len(data.t)), bool)
    fold = with_held(data, FOLDS[1])
    phi = basis(data)
    smooth = noise + 4.0 * np.sin(2.0 * u)[None, :]
    notch = noise + np.where(np.abs(u) < 0.09, 8.0, 0.0)[None, :]
    for r, left in ((smooth, 1.2), (notch, None)):
        out = corrected(r, seen, fold.fit, fold.held, phi)[:, fold.held]
        rms = float(np.sqrt(np.mean(out**2)))
        if left is not None:
            assert rms < left
        else:
            inside = np.abs(u[fold.held]) < 0.09
            assert inside.sum() >= 5
            assert float(np.mean(out[:, inside] ** 2)) > 5.0  # noise: 1


def _null(seed: int):
    case = make_case((), seed, duration_s=DURATION_S)
    return _run(case.trace, case.start)


def _hidden(job: tuple) -> tuple:
    name, fraction, seed = job
    _attr, lo, hi = PLAUSIBLE[name]
    value = lo + fraction * (hi - lo)
    trace, start = warped_case({name: value}, seed, 0.0)
    return value, *run_workflow(trace, start, workers=1, progress=False)


@given(seed=st.integers(0, 10**6))
@EXAMPLES
def test_nothing_is_named_on_a_null_trace(seed: int) -> None:
    result = _null(seed)
    assert result.added == (), result.steps
    assert result.removed == (), result.steps
    assert result.verdict in ("nothing_missing", "unexplained")


@given(name=st.sampled_from(ANY_SIGNAL), fraction=st.floats(0.0, 1.0), seed=st.integers(0, 10**6))
@EXAMPLES
def test_a_hidden_effect_is_named_with_its_value(name: str, fraction: float, seed: int) -> None:
    value, result, data = _hidden((name, fraction, seed))
    assert result.added == (name,), result.steps
    assert result.verdict == "effects_found"
    fitted = result.final.config.effect(name).params()[PLAUSIBLE[name][0]]
    assert abs(fitted / value - 1.0) <= 0.25
    assert result.removed == ()
    # The simulator's own structure, found: nothing structured is left.
    assert not structured(result.scored, data, result.policy, result.rest), result.rest


@given(seed=st.integers(0, 10**6))
@settings(EXAMPLES, max_examples=1)
def test_a_larger_hidden_effect_is_named_when_a_smaller_one_is(seed: int) -> None:
    """Monotone in size: from a deadband a tenth of the plausible least to the plausible most."""
    with ProcessPoolExecutor(max_workers=2, mp_context=get_context("fork")) as pool:
        small, large = pool.map(_hidden, [("deadband", -0.45, seed), ("deadband", 1.0, seed)])
    assert small[1].added in ((), ("deadband",))
    assert large[1].added == ("deadband",)


@given(seed=st.integers(0, 10**6), strength=st.floats(0.15, 0.4))
@settings(EXAMPLES, max_examples=2)
def test_a_difference_outside_the_vocabulary_is_not_named_as_an_effect(
    seed: int, strength: float
) -> None:
    """A throttle curve the simulator does not have: no effect is named for it, nothing of the
    start is called superfluous (the verdict is ``nothing_missing`` or ``unexplained``);
    beside it a hidden deadband is named, and only the deadband. (Its width is then biased by
    the curve: docs/discrepancy.md, "Limits".)"""
    trace, start = warped_case({}, seed, strength)
    result = _run(trace, start)
    assert result.added == (), result.steps
    assert result.removed == (), result.steps
    trace, start = warped_case({"deadband": 0.08}, seed, strength)
    result = _run(trace, start)
    assert result.added == ("deadband",), result.steps


@given(seed=st.integers(0, 10**6), order=st.permutations(range(10)))
@settings(EXAMPLES, max_examples=1)
def test_the_answer_does_not_depend_on_which_blocks_form_a_fold(seed: int, order) -> None:
    """The named effects and the verdict; a start effect at the edge of what the trace shows
    may be kept with one assignment and called superfluous with another."""
    trace, start = warped_case({"dead_time": 0.5}, seed, 0.0)
    folds = tuple((order[2 * i], order[2 * i + 1]) for i in range(5))
    one = _run(trace, start)
    other = _run(trace, start, policy=Policy(folds=folds))
    assert one.added == other.added == ("dead_time",)
    assert one.verdict == other.verdict


def test_cli_end_to_end(tmp_path: Path) -> None:
    """A hidden deadband through the command: report.json's keys and values, model.yaml, the
    report files and the one-line summary."""
    case = make_case(("deadband",), 1, duration_s=DURATION_S)
    measured = tmp_path / "measured.csv"
    write_trace_csv(case.trace, measured)
    out = tmp_path / "out"
    argv = ["discrepancy", "--measured", str(measured), "--start", "t100", "--drop", "deadband"]
    argv += ["--out", str(out), "--quiet", "--workers", "1"]
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        assert main(argv) == 0
    assert text.getvalue().startswith("effects_found: missing deadband; superfluous none")
    report = json.loads((out / "report.json").read_text())
    assert set(report) == {
        "verdict", "missing_effects", "superfluous_effects", "gap_before", "gap_after",
        "base_changes", "at_bound", "alternatives", "rest", "policy",
    }  # fmt: skip
    (named,) = report["missing_effects"]
    assert set(named) == {"name", "params", "uncertainty", "spread", "selection_frequency"}
    assert named["name"] == "deadband"
    assert abs(named["params"]["width"] / case.hidden["deadband"]["width"] - 1.0) <= 0.25
    assert named["uncertainty"]["width"] > 0.0
    assert named["spread"]["width"] >= 0.0
    assert 0.5 <= named["selection_frequency"] <= 1.0
    assert set(report["rest"]) == {"structured", "score", "kind", "gains", "where", "cues"}
    assert set(report["rest"]["gains"]) == {"static", "dynamics", "voltage"}
    assert report["policy"] == json.loads(json.dumps(Policy().__dict__))
    assert report["gap_after"]["rpm_rmse"] < report["gap_before"]["rpm_rmse"]
    assert load_config(out / "model.yaml").effect("deadband") is not None
    assert sorted(p.name for p in out.iterdir()) == sorted(REPORT_FILES)
    details = json.loads((out / "details.json").read_text())
    moves = [m for step in details["steps"] for m in step["moves"]]
    assert any(m["move"] == "add deadband" and m["accepted"] for m in moves)


@pytest.mark.slow
@pytest.mark.skipif(not T200_DATA.is_dir(), reason=f"T200 measurements not found at {T200_DATA}")
def test_t200_bench_data_names_the_deadband(load_script, tmp_path: Path) -> None:
    """Real data: the six T200 sheets as the step trace file a user makes
    (scripts/t200_to_trace.py, docs/discrepancy.md), the t200 preset without its deadband.
    The deadband is named within 10 % of the preset's steady-state calibration (an
    independent fit of the same sheets, scripts/calibrate_t200.py), and no other effect."""
    write_trace_csv(load_script("t200_to_trace").steps_trace(T200_DATA), tmp_path / "t200.csv")
    trace = read_trace_csv(tmp_path / "t200.csv")
    t200 = load_config("t200")
    result, _ = run_workflow(trace, t200, ["deadband"], workers=2, progress=False)
    assert result.added == ("deadband",)
    assert result.removed == ()
    width = result.final.config.effect("deadband").width
    assert abs(width / t200.effect("deadband").width - 1.0) <= 0.10
