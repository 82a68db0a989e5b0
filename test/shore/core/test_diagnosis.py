"""Fault diagnosis: features, training and export, load errors, online = offline, UNKNOWN, CLI."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from thruster_fdd.core.diagnosis.coverage import OPERATING_POINT
from thruster_fdd.core.diagnosis.features import FEATURE_NAMES, window_features
from thruster_fdd.core.diagnosis.model import ClassifierModel, softmax
from thruster_fdd.core.diagnosis.stream import LLR_CLIP, Decision, DiagnosisStream
from thruster_fdd.core.labels import CLASS_NAMES, UNKNOWN
from thruster_fdd.core.nominal.residuals import ResidualStream
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd_shore import cli
from thruster_fdd_shore.core.diagnosis.evaluation import onset_latency
from thruster_fdd_shore.core.diagnosis.metrics import confusion
from thruster_fdd_shore.core.diagnosis.offline import (
    QUIET_TOLERANCE,
    diagnose_trace,
    first_fault,
    label_events,
    overall_label,
    quiet_allowance,
    trace_decisions,
)
from thruster_fdd_shore.core.diagnosis.table3 import Table3Config, run_table3
from thruster_fdd_shore.core.diagnosis.training import (
    BAND_WIDTH,
    ClassifierConfig,
    evidence_floor,
    fit_temperature,
    train_classifier,
)
from thruster_fdd_shore.core.sim.scenario import run_scenario
from thruster_fdd_shore.core.traces.csv_io import write_trace_csv

NOMINAL_DIR = Path(__file__).resolve().parents[3] / "models" / "nominal"
WINDOW_S = 5.0

pytestmark = pytest.mark.skipif(
    not (NOMINAL_DIR / "model_card.json").is_file(), reason="models/nominal not exported"
)


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A models/ folder: the committed nominal model + a classifier trained on small data
    (6 classes x 4 units x 120 s of multilevel commands at 10 Hz, 5 s windows)."""
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("models")
    shutil.copytree(NOMINAL_DIR, root / "nominal")
    traces = [
        run_scenario("t100", c, signal="multilevel", duration_s=120.0, seed=seed)
        for c in CLASS_NAMES
        for seed in (11, 12, 13, 14)
    ]
    config = ClassifierConfig(window_s=WINDOW_S, epochs=300)
    train_classifier(traces, root / "nominal", root / "classifier", seed=0, config=config)
    return root


@pytest.fixture(scope="module")
def loaded(models: Path) -> tuple[NominalModel, ClassifierModel]:
    return NominalModel.load(models / "nominal"), ClassifierModel.load(models / "classifier")


# ---------------------------------------------------------------------------------------------
# Features


def _window(condition: str, seed: int = 3) -> np.ndarray:
    """10 s of telemetry (zero residuals) at the settled 0.75 command step (33..43 s)."""
    tr = run_scenario("t100", condition, signal="steps", duration_s=45.0, seed=seed)
    zeros = np.zeros_like(tr.t)
    window = np.stack([tr.command, tr.voltage, tr.rpm, tr.current, zeros, zeros], axis=1)
    return window[330:430]


def test_window_features_shape_nan_and_errors() -> None:
    w = _window("nominal_15v")
    f = window_features(w, 0.1)
    assert f.shape == (len(FEATURE_NAMES),)
    idle = np.zeros((50, 6))
    idle[:, 1] = 15.0
    fi = window_features(idle, 0.1)
    assert math.isnan(fi[FEATURE_NAMES.index("rel_res_rpm")])
    assert fi[FEATURE_NAMES.index("voltage_mean")] == pytest.approx(15.0)
    with pytest.raises(ValueError, match="shape"):
        window_features(np.zeros((50, 5)), 0.1)
    bad = w.copy()
    bad[3, 2] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        window_features(bad, 0.1)


def test_broken_blade_ripple_and_fouling_torque_features() -> None:
    names = FEATURE_NAMES
    nom = window_features(_window("nominal_15v"), 0.1)
    blade = window_features(_window("broken_blade_2"), 0.1)
    fouled = window_features(_window("biofouling"), 0.1)
    ripple = names.index("current_ripple")
    assert blade[ripple] > 2.0 * nom[ripple]
    k = names.index("power_per_speed3")
    assert fouled[k] > 1.15 * nom[k] > 1.15 * blade[k]


# ---------------------------------------------------------------------------------------------
# Calibration, metrics


def test_fit_temperature_recovers_overconfidence() -> None:
    rng = np.random.default_rng(0)
    true_logits = rng.normal(size=(4000, 6)) * 2.0
    p = softmax(true_logits)
    y = np.array([rng.choice(6, p=row) for row in p])
    assert fit_temperature(true_logits * 3.0, y) == pytest.approx(3.0, rel=0.1)
    assert fit_temperature(true_logits, y) == pytest.approx(1.0, rel=0.1)


def test_confusion_counts_unknown_in_last_column() -> None:
    truth = np.array(["a", "a", "b", "b"], dtype=object)
    pred = np.array(["a", "unknown", "a", "b"], dtype=object)
    assert confusion(truth, pred, ("a", "b")).tolist() == [[1, 0, 1], [1, 1, 0]]


# ---------------------------------------------------------------------------------------------
# Training, card, load errors


def test_card_records_classes_features_window_and_pair(models: Path) -> None:
    card = json.loads((models / "classifier" / "model_card.json").read_text())
    assert card["kind"] == "classifier"
    assert card["class_names"] == list(CLASS_NAMES)
    assert card["features"] == list(FEATURE_NAMES)
    assert card["window_s"] == WINDOW_S
    assert card["nominal_model_id"] == NominalModel.load(models / "nominal").model_id
    assert len(card["training_data_digest"]) == 64
    assert 0.0 <= card["training_metrics"]["heldout"]["balanced_accuracy"] <= 1.0
    assert card["temperature"] > 0


def _broken_copy(models: Path, tmp_path: Path) -> Path:
    d = tmp_path / "clf"
    shutil.copytree(models / "classifier", d)
    return d


def test_load_errors_name_the_file_and_the_problem(models: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="model directory missing"):
        ClassifierModel.load(tmp_path / "nope")
    d = _broken_copy(models, tmp_path)
    card_path = d / "model_card.json"
    card = json.loads(card_path.read_text())

    card_path.write_text("{not json")
    with pytest.raises(ValueError, match=r"model_card\.json: not valid JSON"):
        ClassifierModel.load(d)
    card_path.write_text(json.dumps({**card, "class_names": ["a", "b"]}))
    with pytest.raises(ValueError, match=r"model_card\.json: class_names are"):
        ClassifierModel.load(d)
    card_path.write_text(json.dumps({**card, "kind": "nominal"}))
    with pytest.raises(ValueError, match=r"model_card\.json: kind is 'nominal'"):
        ClassifierModel.load(d)
    with pytest.raises(ValueError, match=r"model_card\.json: kind is 'nominal'"):
        ClassifierModel.load(models / "nominal")
    card_path.write_text(json.dumps({k: v for k, v in card.items() if k != "temperature"}))
    with pytest.raises(ValueError, match=r"missing field.*temperature"):
        ClassifierModel.load(d)
    for floor in (-0.1, 1.5, "0.2", True):
        coverage = {**card["coverage"], "evidence_floor": {"min_command_abs": floor}}
        card_path.write_text(json.dumps({**card, "coverage": coverage}))
        with pytest.raises(ValueError, match=r"malformed coverage\.evidence_floor"):
            ClassifierModel.load(d)
    card_path.write_text(json.dumps(card))
    for name in ("model.pt2", "weights.npz"):
        saved = (d / name).read_bytes()
        (d / name).write_bytes(saved[:-1] + bytes([saved[-1] ^ 1]))
        with pytest.raises(ValueError, match=rf"{name}: SHA-256 differs"):
            ClassifierModel.load(d)
        (d / name).unlink()
        with pytest.raises(ValueError, match=rf"{name}: missing"):
            ClassifierModel.load(d)
        (d / name).write_bytes(saved)
    card_path.unlink()
    with pytest.raises(ValueError, match=r"model_card\.json: model card missing"):
        ClassifierModel.load(d)


def test_classifier_of_another_nominal_model_is_refused(models: Path, tmp_path: Path) -> None:
    d = _broken_copy(models, tmp_path)
    card = json.loads((d / "model_card.json").read_text())
    (d / "model_card.json").write_text(json.dumps({**card, "nominal_model_id": "nominal-x"}))
    trace = run_scenario("t100", "nominal_15v", signal="steps", duration_s=20.0)
    with pytest.raises(ValueError, match="made with nominal model 'nominal-x'"):
        diagnose_trace(trace, models / "nominal", d)


def test_training_refuses_unlabelled_or_incomplete_data(models: Path) -> None:
    trace = run_scenario("t100", "nominal_15v", signal="steps", duration_s=30.0)
    unlabelled = type(trace)(trace.t, trace.command, trace.voltage, trace.rpm, trace.current)
    with pytest.raises(ValueError, match="no condition column or labels"):
        train_classifier([unlabelled], models / "nominal", None)
    with pytest.raises(ValueError, match="no training window of class"):
        train_classifier([trace, trace], models / "nominal", None)


# ---------------------------------------------------------------------------------------------
# Online stream and offline diagnosis


def test_online_stream_equals_offline_diagnose_trace(
    models: Path, loaded: tuple[NominalModel, ClassifierModel]
) -> None:
    trace = run_scenario(
        "t100", "nominal_15v", signal="mission", duration_s=60.0, seed=21,
        fault_at_s=30.0, fault_condition="broken_blade_2",
    )  # fmt: skip
    offline = diagnose_trace(trace, models / "nominal", models / "classifier")
    nominal, classifier = loaded
    residuals = ResidualStream(nominal)
    residuals.reset()
    stream = DiagnosisStream(classifier)
    online = []
    columns = (trace.t, trace.command, trace.voltage, trace.rpm, trace.current)
    for seq, row in enumerate(zip(*columns, strict=True)):
        t, c, v, r, i = (float(x) for x in row)
        s = residuals.push(t, c, v, r, i, sequence=seq)
        if s is None:
            continue
        d = stream.push(t, c, v, r, i, s.residual_rpm, s.residual_current_a, s.valid)
        if d is not None:
            online.append(d)
    windows = offline["windows"]
    expected = round((60.0 - 2.0 - WINDOW_S) / 1.0)  # 2 s nominal warm-up, then one per hop
    assert abs(len(windows) - expected) <= 1
    assert len(online) == len(windows)
    for d, w in zip(online, windows, strict=True):
        assert (d.t_start_s, d.t_s, d.label) == (w["t_start"], w["t_end"], w["label"])
        assert d.probabilities == w["probabilities"]
        assert sum(d.probabilities.values()) == pytest.approx(1.0)
        assert d.t_s - d.t_start_s == pytest.approx(WINDOW_S - 0.1)


def test_decisions_every_hop_gaps_and_invalid_samples(
    loaded: tuple[NominalModel, ClassifierModel],
) -> None:
    _, classifier = loaded
    stream = DiagnosisStream(classifier, hop_s=0.5, hysteresis=3)
    n = classifier.window_samples
    row = (0.6, 15.0, 2600.0, 3.0, 0.0, 0.0)
    out = [stream.push(0.1 * k, *row, True) for k in range(n + 20)]
    decisions = [d for d in out if d is not None]
    assert out[n - 2] is None
    assert out[n - 1] is not None  # first decision: the window just filled
    assert len(decisions) == 1 + 20 // 5  # then every 0.5 s = 5 samples
    for d in decisions:
        assert (d.label == UNKNOWN) == (d.reason != "")
    assert stream.push(0.1 * (n + 20), *row, False) is None  # invalid: skipped
    # a 2 s gap restarts the window: no decision until it is full again
    t0 = 0.1 * (n + 20) + 2.0
    after = [stream.push(t0 + 0.1 * k, *row, True) for k in range(n)]
    assert all(d is None for d in after[:-1])
    assert after[-1] is not None
    with pytest.raises(ValueError, match="hysteresis"):
        DiagnosisStream(classifier, hysteresis=0)


def test_idle_windows_give_no_evidence_and_keep_the_label(
    loaded: tuple[NominalModel, ClassifierModel],
) -> None:
    _, classifier = loaded
    n = classifier.window_samples
    driven = (0.6, 15.0, 2600.0, 3.0, 0.0, 0.0)
    idle = (0.0, 15.0, 0.0, 0.05, 0.0, 0.0)  # no turning sample: active_fraction 0
    rows = [driven] * (n + 30) + [idle] * (3 * n) + [driven] * (2 * n)
    stream = DiagnosisStream(classifier, hop_s=0.1)
    out = [stream.push(0.1 * k, *row, True) for k, row in enumerate(rows)]
    decisions = [d for d in out if d is not None]
    quiet = [d for d in decisions if d.reason == "low_excitation"]
    assert len(quiet) > 50
    assert all(d.label == UNKNOWN for d in quiet)
    assert len({d.fault_evidence for d in quiet}) == 1, "idle windows change no evidence"
    before = next(d for d in reversed(decisions[: decisions.index(quiet[0])]) if not d.reason)
    again = next(d for d in decisions[decisions.index(quiet[-1]) + 1 :] if not d.reason)
    assert again.label == before.label  # the label stood through the idle stretch
    with pytest.raises(ValueError, match="evidence_tau_s"):
        DiagnosisStream(classifier, evidence_tau_s=-1.0)
    with pytest.raises(ValueError, match="excitation_range"):
        DiagnosisStream(classifier, excitation_range=(0.6, 0.3))


def test_card_carries_the_training_region_and_its_calibration(models: Path) -> None:
    card = json.loads((models / "classifier" / "model_card.json").read_text())
    assert card["coverage"]["coordinates"] == list(OPERATING_POINT)
    assert card["coverage"]["threshold"] >= 1.0
    lo, hi = card["coverage"]["summary"]["voltage_mean"]
    assert 11.0 < lo < hi < 16.0
    assert card["calibration"]["windows"] > 0
    assert 0.0 <= card["calibration"]["ece"] <= 1.0
    floor = card["coverage"]["evidence_floor"]
    assert floor["min_accuracy"] == ClassifierConfig().min_band_accuracy
    assert sum(n for _, n, _ in floor["bands"]) > 0
    reached = [lower for lower, _, accuracy in floor["bands"] if accuracy >= floor["min_accuracy"]]
    assert floor["min_command_abs"] == (reached[0] if reached else None)
    classifier = ClassifierModel.load(models / "classifier")
    assert classifier.min_command_abs == (reached[0] if reached else math.inf)
    trained = classifier.coverage.points[len(classifier.coverage.points) // 2]
    assert classifier.coverage.covers(trained * classifier.coverage.resolution)[0]
    assert not classifier.coverage.covers(np.array([0.5, 0.5, 0.1, 24.0]))[0]


@given(
    bands=st.lists(
        st.tuples(st.integers(0, 19), st.integers(1, 400), st.floats(0.0, 1.0)),
        min_size=1,
        max_size=8,
        unique_by=lambda b: b[0],
    ),
    need=st.floats(0.5, 1.0),
)
@settings(max_examples=60, deadline=None)
def test_the_evidence_floor_is_the_lowest_band_told_apart_well_enough(
    bands: list[tuple[int, int, float]], need: float
) -> None:
    rng = np.random.default_rng(0)
    command, fault_p, is_fault, expected = [], [], [], {}
    for band, n, share in bands:
        right = round(share * n)
        truth = rng.random(n) < 0.5
        says = truth.copy()
        says[right:] = ~says[right:]
        command += list((band + rng.uniform(0.01, 0.99, n)) * BAND_WIDTH)
        fault_p += list(np.where(says, 0.9, 0.1))
        is_fault += list(truth)
        expected[band] = round((right + 1) / (n + 2), 4)
    entry = evidence_floor(np.array(command), np.array(fault_p), np.array(is_fault), need)
    assert [b[0] for b in entry["bands"]] == [round(b * BAND_WIDTH, 6) for b in sorted(expected)]
    passing = [b for b in sorted(expected) if expected[b] >= need]
    floor = entry["min_command_abs"]
    assert floor == (round(passing[0] * BAND_WIDTH, 6) if passing else None)
    stricter = evidence_floor(np.array(command), np.array(fault_p), np.array(is_fault), 1.0)
    assert stricter["min_command_abs"] is None  # (right + 1) / (n + 2) < 1: a band never proves
    # everything; and a band of ten windows all right (11 / 12) is not 95 % evidence
    few = evidence_floor(np.full(10, 0.32), np.full(10, 0.9), np.ones(10, bool), 0.95)
    assert few["min_command_abs"] is None


def test_healthy_and_fouled_are_told_apart_on_an_unseen_unit(
    loaded: tuple[NominalModel, ClassifierModel],
) -> None:
    nominal, classifier = loaded
    for cond in ("nominal_15v", "biofouling"):
        trace = run_scenario("t100", cond, signal="multilevel", duration_s=60.0, seed=31)
        raws = [d.raw_label for d in trace_decisions(trace, nominal, classifier)]
        assert len(raws) > 40
        assert np.mean(np.array(raws) == cond) >= 0.8, (cond, raws)


def test_unknown_on_input_unlike_every_class(
    loaded: tuple[NominalModel, ClassifierModel],
) -> None:
    nominal, classifier = loaded
    wild = run_scenario("t100", "nominal_15v", signal="multilevel", duration_s=40.0,
                        voltage=24.0, seed=31)  # fmt: skip
    raws = np.array([d.raw_label for d in trace_decisions(wild, nominal, classifier)])
    assert len(raws) > 20
    assert np.mean(raws == UNKNOWN) >= 0.9
    usual = run_scenario("t100", "nominal_13v", signal="multilevel", duration_s=40.0, seed=31)
    raws = np.array([d.raw_label for d in trace_decisions(usual, nominal, classifier)])
    assert np.mean(raws == UNKNOWN) <= 0.2


def test_onset_latency_needs_the_label_to_stay() -> None:
    def d(t: float, label: str) -> Decision:
        return Decision(t, label, label, {}, 1.0, 10.0, t - 10.0, 0.0)

    seq = [d(50, "nominal_15v"), d(61, "biofouling"), d(62, "nominal_15v"), d(63, "biofouling"),
           d(64, "biofouling")]  # fmt: skip
    assert onset_latency(seq, "biofouling", 60.0) == pytest.approx(3.0)
    assert onset_latency(seq[:3], "biofouling", 60.0) == math.inf


def _published(*labels: tuple[float, str, str]) -> list[Decision]:
    """Decisions (t, published label, window's own label), windows of 20 s, hop 1 s."""
    return [Decision(t, lab, raw, {}, 0.9, 20.0, t - 20.0, 0.0) for t, lab, raw in labels]


@given(
    steps=st.lists(
        st.tuples(st.sampled_from([0.0, 0.01, 0.05]), st.floats(-LLR_CLIP, LLR_CLIP)),
        min_size=1,
        max_size=40,
    ),
    threshold=st.floats(0.5, 20.0),
)
@settings(max_examples=50, deadline=None)
def test_the_quiet_allowance_is_the_largest_allowance_some_run_of_windows_beats(
    steps: list[tuple[float, float]], threshold: float
) -> None:
    # A CUSUM with allowance k reaches h when some run of windows has sum(g (r - k)) >= h, so
    # the smallest quiet allowance is the largest (sum(g r) - h) / sum(g) over all runs.
    decisions = [
        Decision(float(i), "unknown", "unknown", {}, 0.5, 20.0, i - 20.0, 0.0,
                 fault_threshold=threshold, fault_ratio=r, evidence_weight=g)
        for i, (g, r) in enumerate(steps)
    ]  # fmt: skip
    runs = [
        (sum(g * r for g, r in steps[i:j]) - threshold) / sum(g for g, _ in steps[i:j])
        for i in range(len(steps))
        for j in range(i + 1, len(steps) + 1)
        if sum(g for g, _ in steps[i:j]) > 0.0
    ]
    quiet = quiet_allowance(decisions)
    if not runs:
        assert quiet is None
        return
    assert max(runs) - 1e-9 <= quiet <= max(runs) + QUIET_TOLERANCE + 1e-9


def test_the_quiet_allowance_is_where_a_faulty_trace_stops_publishing() -> None:
    nominal = NominalModel.load(NOMINAL_DIR)
    classifier = ClassifierModel.load(NOMINAL_DIR.parent / "classifier")
    trace = run_scenario("t100", "broken_blade_2", signal="multilevel", duration_s=90.0, seed=41)

    def decide(allowance: float) -> list[Decision]:
        return trace_decisions(trace, nominal, classifier, unit_allowance=allowance)

    quiet = quiet_allowance(decide(0.0))
    assert quiet is not None
    assert 2 * QUIET_TOLERANCE < quiet < LLR_CLIP
    assert quiet_allowance(decide(quiet)) == quiet, "it does not depend on the allowance used"
    assert first_fault(decide(quiet)) is None
    assert first_fault(decide(quiet - 2 * QUIET_TOLERANCE))["label"] == "broken_blade_2"


def test_events_first_fault_and_an_overall_a_fault_wins() -> None:
    seq = _published(
        *[(float(t), "unknown", "unknown") for t in (20, 21)],
        *[(float(t), "nominal_15v", "nominal_15v") for t in range(22, 95)],
        (95.0, "nominal_15v", "broken_blade_1"),
        (96.0, "nominal_15v", "broken_blade_1"),
        *[(float(t), "broken_blade_1", "broken_blade_1") for t in range(97, 105)],
        *[(float(t), "nominal_15v", "nominal_15v") for t in range(105, 180)],
    )
    assert [(e["t"], e["label"]) for e in label_events(seq)] == [
        (20.0, "unknown"), (22.0, "nominal_15v"), (97.0, "broken_blade_1"), (105.0, "nominal_15v"),
    ]  # fmt: skip
    fault = first_fault(seq)
    assert fault == {"label": "broken_blade_1", "t": 97.0, "onset_t": 85.0}
    # 8 s of a fault against 148 s of nominal: the fault is the answer, not averaged away.
    assert overall_label(seq)["label"] == "broken_blade_1"
    healthy = _published(*[(float(t), "nominal_13v", "nominal_13v") for t in range(20, 60)])
    assert first_fault(healthy) is None
    assert overall_label(healthy)["label"] == "nominal_13v"
    assert overall_label([]) == {"label": UNKNOWN, "confidence": 0.0}


def test_diagnose_expect_is_the_exit_code_for_ci(tmp_path: Path) -> None:
    """On the committed fault bag (broken_blade_1 from 90 s) with the committed models."""
    bag = Path(__file__).resolve().parents[3] / "bags" / "fault_broken_blade_1_at_90s.mcap"
    models = NOMINAL_DIR.parent
    base = ["diagnose", str(bag), "--models", str(models)]
    js = tmp_path / "d.json"
    assert cli.main([*base, "--expect", "broken_blade_1@90", "--json", str(js)]) == 0
    result = json.loads(js.read_text())
    fault = result["first_fault"]
    assert fault["label"] == "broken_blade_1"
    assert 90.0 <= fault["t"] - result["start"] <= 150.0
    assert abs(fault["onset_t"] - result["start"] - 90.0) <= 20.0
    assert result["overall"]["label"] == "broken_blade_1"
    assert cli.main([*base, "--expect", "broken_blade_1"]) == 0
    late = f"broken_blade_1@{fault['t'] - result['start'] + 5.0:.1f}"
    assert cli.main([*base, "--expect", late]) == 1, "published before that"
    assert cli.main([*base, "--expect", "biofouling"]) == 1
    for bad in ("rusty", "broken_blade_1@soon"):
        with pytest.raises(SystemExit) as exit_info:  # argparse: one line, exit 2
            cli.main([*base, "--expect", bad])
        assert exit_info.value.code == 2
    assert cli.main(["diagnose", str(tmp_path / "none"), "--models", str(models)]) == 2


# ---------------------------------------------------------------------------------------------
# Command line


def test_cli_train_and_diagnose_json_has_design_keys(models: Path, tmp_path: Path) -> None:
    data = tmp_path / "data"
    for c in CLASS_NAMES:
        for seed in (41, 42):
            trace = run_scenario("t100", c, signal="multilevel", duration_s=40.0, seed=seed)
            write_trace_csv(trace, data / f"{c}_{seed}.csv")
    out = tmp_path / "models"
    shutil.copytree(models / "nominal", out / "nominal")
    args = ["train", "classifier", "--data", str(data), "--nominal", str(out / "nominal"),
            "--out", str(out / "classifier"), "--window", "5", "--epochs", "50"]  # fmt: skip
    assert cli.main(args) == 0
    js = tmp_path / "diag.json"
    assert cli.main(["diagnose", str(data / "biofouling_41.csv"), "--models", str(out),
                     "--json", str(js)]) == 0  # fmt: skip
    result = json.loads(js.read_text())
    assert set(result) == {
        "start",
        "overall",
        "events",
        "first_fault",
        "unknown_reasons",
        "fault_threshold",
        "quiet_allowance",
        "windows",
    }
    assert result["quiet_allowance"] is None or math.isfinite(result["quiet_allowance"])
    assert set(result["overall"]) == {"label", "confidence"}
    for e in result["events"]:
        assert set(e) == {"t", "label", "confidence"}
    assert result["first_fault"] is None or set(result["first_fault"]) == {"label", "t", "onset_t"}
    assert result["overall"]["label"] in (*CLASS_NAMES, UNKNOWN)
    assert result["windows"]
    for w in result["windows"]:
        assert {"t_start", "t_end", "label", "probabilities", "reason", "covered"} <= set(w)
        assert set(w["probabilities"]) == set(CLASS_NAMES)
        assert w["t_start"] < w["t_end"]
    assert cli.main(["diagnose", str(tmp_path / "none.csv"), "--models", str(out)]) == 2
    assert cli.main(["diagnose", str(data / "biofouling_41.csv"), "--models", str(data)]) == 2


def test_table3_protocol_smoke() -> None:
    nominal = NominalModel.load(NOMINAL_DIR)
    cfg = Table3Config(train_samples=400, test_samples=200, mlp_epochs=300, lstm_epochs=2)
    rows = run_table3(cfg, nominal)
    assert [(r["model"], r["inputs"]) for r in rows] == [
        ("MLP", "signals"), ("MLP", "residuals"), ("LSTM", "signals"), ("LSTM", "residuals"),
    ]  # fmt: skip
    for r in rows:
        m = np.asarray(r["confusion"])
        assert m.shape == (6, 6)
        np.testing.assert_allclose(m.sum(axis=1), 1.0)
        assert len(r["cv_folds"]) == 3
        counts = np.asarray(r["counts"])
        assert counts.sum() == 6 * (200 if r["model"] == "MLP" else 200 - cfg.lookback + 1)
        assert r["test_accuracy"] == pytest.approx(np.trace(counts) / counts.sum())
    # the supply voltage is among the four signals: the three nominal classes are told apart
    mlp_signals = np.asarray(rows[0]["confusion"])
    assert np.mean(np.diag(mlp_signals)[1:3]) > 0.9
