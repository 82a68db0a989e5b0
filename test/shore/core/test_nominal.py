"""Tests of the nominal model: scaler, export/load contract, online step vs batch, CLI, Table 2."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from thruster_fdd.core.artifact import CARD_FILE, PROGRAM_FILE, WEIGHTS_FILE, file_sha256
from thruster_fdd.core.nominal.card import read_nominal_card
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd.core.nominal.spec import IqrScaler, ModelSpec
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore import cli
from thruster_fdd_shore.core.nominal.evaluation import (
    ProtocolConfig,
    run_table2,
    spec_for,
    table2_markdown,
)
from thruster_fdd_shore.core.nominal.export import check_program, load_program
from thruster_fdd_shore.core.nominal.training import (
    TrainConfig,
    lag_windows,
    predict_sequence,
    resample,
    time_series_folds,
    train_model,
    train_nominal,
)
from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import simulate
from thruster_fdd_shore.core.sim.signals import make_signal
from thruster_fdd_shore.core.traces.csv_io import write_trace_csv

torch.set_num_threads(1)
FAST = TrainConfig(epochs=4, finetune_epochs=2, horizon=10, batch_size=64)
SPEC = ModelSpec("narx", (8,), input_lags=6, output_lags=2, feedback=("rpm",))


def _trace(
    signal: str = "multilevel", duration: float = 60.0, seed: int = 1, cond: str = "nominal_15v"
) -> Trace:
    t, u = make_signal(signal, duration, 10.0, seed=seed)
    return simulate(load_config("t100"), t, u, cond, seed=seed)


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("nominal")
    train_nominal([_trace(), _trace("sine:0.02", seed=2)], out, spec=SPEC, config=FAST)
    return out


@pytest.fixture(scope="module")
def sp_model_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A series-parallel export with the default spec of that mode (both outputs fed back)."""
    out = tmp_path_factory.mktemp("nominal_sp")
    cfg = replace(FAST, mode="series-parallel")
    train_nominal([_trace(), _trace("sine:0.02", seed=2)], out, config=cfg)
    return out


def _copy(src: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "m"
    shutil.copytree(src, dst)
    return dst


def test_scaler_round_trip_and_floor() -> None:
    rng = np.random.default_rng(0)
    x = np.stack([rng.normal(0, 1, 500), 15.0 + rng.normal(0, 0.01, 500)], axis=1)
    sc = IqrScaler.fit(("command", "voltage"), x)
    assert np.allclose(sc.inverse(sc.transform(x)), x)
    q25, q75 = np.percentile(x[:, 0], [25, 75])
    assert sc.scale[0] == pytest.approx(q75 - q25)
    assert sc.scale[1] == 1.0  # the voltage IQR (~0.013 V) is floored at 1 V
    again = IqrScaler.from_dict(sc.names, json.loads(json.dumps(sc.to_dict())))
    assert again == sc


@pytest.mark.parametrize("trained", ["parallel", "series-parallel"])
@pytest.mark.parametrize("mode", ["series-parallel", "parallel"])
def test_online_step_equals_batch_predict(
    model_dir: Path, sp_model_dir: Path, trained: str, mode: str
) -> None:
    model = NominalModel.load(model_dir if trained == "parallel" else sp_model_dir)
    assert model.card.mode == trained
    model.mode = mode
    tr = _trace("mission", 40.0, seed=5, cond="biofouling")
    rpm, cur = model.predict(tr.command, tr.voltage, tr.rpm, tr.current)
    online = [model.step(*s) for s in zip(tr.command, tr.voltage, tr.rpm, tr.current, strict=True)]
    w = model.warmup_samples
    assert all(p is None for p in online[:w])
    assert np.isnan(rpm[:w]).all()
    steps = np.array(online[w:], dtype=float)
    assert np.allclose(steps[:, 0], rpm[w:], rtol=1e-9, atol=1e-6)
    assert np.allclose(steps[:, 1], cur[w:], rtol=1e-9, atol=1e-9)
    # the two modes differ (parallel ignores the measured outputs after the warm-up)
    model.mode = "parallel" if mode == "series-parallel" else "series-parallel"
    other, _ = model.predict(tr.command, tr.voltage, tr.rpm, tr.current)
    assert not np.allclose(other[w:], rpm[w:])
    model.reset()
    assert model.step(*(float(v[0]) for v in (tr.command, tr.voltage, tr.rpm, tr.current))) is None


def test_series_parallel_export_feeds_back_both_outputs(sp_model_dir: Path) -> None:
    card = read_nominal_card(sp_model_dir)
    assert card.mode == "series-parallel"
    assert card.feedback == ("rpm", "current")
    assert card.training_metrics["validation"]["mode"] == "series-parallel"


def test_series_parallel_beats_persistence_on_held_out_data() -> None:
    # Train one step ahead, test on unseen sines of higher frequency (new noise): the NARX must
    # beat "next sample = last sample" by a clear margin (MSE < 0.6 x) on both outputs.
    # (Held-out multilevel steps are harder: a 150-epoch run measured current MSE 0.49 x
    # persistence, a 100-epoch one 1.13 x, so that case is not asserted; docs/nominal_model.md.)
    spec = ModelSpec("narx", (32,), input_lags=20, output_lags=2, feedback=("rpm", "current"))
    train = [resample(_trace(duration=120.0), 0.1), resample(_trace("sine:0.02", 60.0, 2), 0.1)]
    net, _ = train_model(spec, train, TrainConfig(mode="series-parallel", epochs=100))
    for signal, seed in (("sine:0.03", 9), ("sine:0.04", 10)):
        test = resample(_trace(signal, 60.0, seed=seed), 0.1)
        pred = predict_sequence(net, test, "series-parallel")
        k = slice(spec.warmup, None)
        mse_model = np.mean((pred[k] - test.y[k]) ** 2, axis=0)
        mse_persist = np.mean((test.y[spec.warmup - 1 : -1] - test.y[k]) ** 2, axis=0)
        assert np.all(mse_model < 0.6 * mse_persist), (signal, mse_model / mse_persist)


def test_step_rejects_non_finite(model_dir: Path) -> None:
    model = NominalModel.load(model_dir)
    with pytest.raises(ValueError, match="non-finite"):
        model.step(0.1, float("nan"), 0.0, 0.0)


def test_fast_path_equals_exported_program(model_dir: Path) -> None:
    model = NominalModel.load(model_dir)
    rng = np.random.default_rng(3)
    u = np.stack([rng.uniform(-1, 1, (5, 6)), rng.uniform(11, 16, (5, 6))], axis=-1)
    y = np.stack([rng.uniform(-4000, 4000, (5, 2)), rng.uniform(0, 10, (5, 2))], axis=-1)
    program = load_program(model_dir)
    with torch.inference_mode():
        ref = program.module()(torch.tensor(u).float(), torch.tensor(y).float()).numpy()
    fast = model.weights.predict(u, y)
    assert np.allclose(fast, ref, rtol=1e-4, atol=np.array([0.05, 1e-4]))
    tampered = replace(model.weights, out_b=model.weights.out_b + 0.1)
    with pytest.raises(ValueError, match="differs"):
        check_program(program, tampered, Path("x.pt2"))


def test_card_contract(model_dir: Path) -> None:
    card = read_nominal_card(model_dir)
    assert card.kind == "nominal"
    assert card.inputs == ("command", "voltage")
    assert card.outputs == ("rpm", "current")
    assert card.lookbacks == {"input": 6, "output": 2}
    assert card.class_names == ()
    assert set(card.scaling) == {"command", "voltage", "rpm", "current"}
    assert card.mode == "parallel"
    assert card.model_id.startswith("nominal-narx-")
    assert len(card.training_data_digest) == 64
    assert {"train", "validation"} <= set(card.training_metrics)


def test_load_missing(tmp_path: Path, model_dir: Path) -> None:
    with pytest.raises(ValueError, match="model directory missing"):
        NominalModel.load(tmp_path / "nope")
    d = _copy(model_dir, tmp_path)
    (d / CARD_FILE).unlink()
    with pytest.raises(ValueError, match=rf"{CARD_FILE}: model card missing"):
        NominalModel.load(d)
    for name in (PROGRAM_FILE, WEIGHTS_FILE):
        d2 = tmp_path / f"m2-{name}"
        shutil.copytree(model_dir, d2)
        (d2 / name).unlink()
        with pytest.raises(ValueError, match=rf"{name}: missing"):
            NominalModel.load(d2)


def test_load_corrupt(tmp_path: Path, model_dir: Path) -> None:
    d = _copy(model_dir, tmp_path)
    (d / CARD_FILE).write_text("{not json")
    with pytest.raises(ValueError, match=rf"{CARD_FILE}: not valid JSON"):
        NominalModel.load(d)
    shutil.copy(model_dir / CARD_FILE, d / CARD_FILE)
    (d / PROGRAM_FILE).write_bytes(b"garbage")
    with pytest.raises(ValueError, match=rf"{PROGRAM_FILE}: SHA-256 differs"):
        NominalModel.load(d)
    with pytest.raises(ValueError, match=rf"{PROGRAM_FILE}: SHA-256 differs"):
        load_program(d)


def _record_digests(d: Path) -> None:
    """Make the card's digests those of the files as they are now (a deliberate forgery)."""
    raw = json.loads((d / CARD_FILE).read_text())
    raw["files"] = {name: file_sha256(d / name) for name in raw["files"]}
    (d / CARD_FILE).write_text(json.dumps(raw))


def test_weights_are_data_never_code(tmp_path: Path, model_dir: Path) -> None:
    d = _copy(model_dir, tmp_path)
    (d / WEIGHTS_FILE).write_bytes(b"garbage")
    _record_digests(d)
    with pytest.raises(ValueError, match=rf"{WEIGHTS_FILE}: not a weights file"):
        NominalModel.load(d)
    # An object array is stored pickled inside the .npz: loading must refuse it, not run it.
    marker = tmp_path / "ran"
    payload = np.array([_Payload(str(marker))], dtype=object)
    with (d / WEIGHTS_FILE).open("wb") as f:
        np.savez(f, **{"out.bias": payload})
    _record_digests(d)
    with pytest.raises(ValueError, match=rf"{WEIGHTS_FILE}: not a weights file"):
        NominalModel.load(d)
    assert not marker.exists()


def test_weights_that_unpack_too_large_are_refused_unread(tmp_path: Path, model_dir: Path) -> None:
    d = _copy(model_dir, tmp_path)
    with (d / WEIGHTS_FILE).open("wb") as f:  # 72 MB of zeros, about 70 KB compressed
        np.savez_compressed(f, **{"out.bias": np.zeros(9_000_000)})
    _record_digests(d)
    with pytest.raises(ValueError, match=rf"{WEIGHTS_FILE}: \d+ bytes of arrays unpacked"):
        NominalModel.load(d)


class _Payload:
    """Creates a file when unpickled."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self) -> tuple:
        return (Path.touch, (Path(self.path),))


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("kind", "classifier", "kind is 'classifier', expected 'nominal'"),
        ("inputs", ["command"], "inputs is .*expected"),
        ("outputs", ["current", "rpm"], "outputs is .*expected"),
        ("mode", "open-loop", "mode is 'open-loop'"),
        ("lookbacks", {"input": 7, "output": 2}, "does not match .*shape"),
        ("hidden", [16], "does not match .*shape"),
        ("scaling", None, "scaling of inputs differs"),
        ("sample_time_s", "0.1", "field 'sample_time_s' has type str"),
    ],
)
def test_load_mismatched(
    tmp_path: Path, model_dir: Path, field: str, value: object, message: str
) -> None:
    d = _copy(model_dir, tmp_path)
    raw = json.loads((d / CARD_FILE).read_text())
    if field == "scaling":
        raw["scaling"]["voltage"]["center"] += 1.0
    else:
        raw[field] = value
    (d / CARD_FILE).write_text(json.dumps(raw))
    with pytest.raises(ValueError, match=message) as err:
        NominalModel.load(d)
    assert str(d) in str(err.value)


def test_training_is_reproducible(tmp_path: Path) -> None:
    data = [_trace(duration=30.0)]
    a = train_nominal(data, tmp_path / "a", spec=SPEC, config=FAST, validation_fraction=0)
    b = train_nominal(data, tmp_path / "b", spec=SPEC, config=FAST, validation_fraction=0)
    c = train_nominal(data, tmp_path / "c", spec=SPEC, config=FAST, seed=1, validation_fraction=0)
    assert a.model_id == b.model_id != c.model_id


def test_time_series_folds_validation_follows_training() -> None:
    folds = time_series_folds(1000, 3)
    assert folds[0][0] == 500
    assert folds[-1][1] == 1000
    for (train_end, val_end), nxt in zip(folds, [*folds[1:], None], strict=True):
        assert train_end < val_end
        if nxt is not None:
            assert nxt[0] == val_end  # the next fold trains on everything seen so far
    with pytest.raises(ValueError, match="n_folds"):
        time_series_folds(100, 0)


def test_lag_windows_use_the_past_only() -> None:
    seq = resample(_trace(duration=5.0), 0.1)
    u_h, y_h, target = lag_windows(seq, 3, 2)
    assert np.array_equal(u_h[0], seq.u[0:3])
    assert np.array_equal(y_h[0], seq.y[1:3])
    assert np.array_equal(target[0], seq.y[3])


@pytest.mark.parametrize("arch", ["mlp", "mlp_tdd", "narx_deadband", "lstm", "gru"])
def test_other_regressors_train_and_predict(arch: str) -> None:
    spec = spec_for(arch)
    spec = replace(spec, hidden=(8,), input_lags=min(spec.input_lags, 6))
    seq = resample(_trace(duration=40.0), 0.1)
    net, _ = train_model(spec, [seq], replace(FAST, chunk=100))
    from thruster_fdd_shore.core.nominal.training import predict_sequence

    pred = predict_sequence(net, seq)
    assert pred.shape == (len(seq.u), 2)
    assert np.isfinite(pred[spec.warmup :]).all()


def test_cli_train_then_evaluate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    csv = tmp_path / "nominal.csv"
    write_trace_csv(_trace(duration=40.0), csv)
    out = tmp_path / "model"
    argv = ["train", "nominal", "--data", str(csv), "--out", str(out)]
    assert cli.main([*argv, "--epochs", "20", "--finetune-epochs", "3"]) == 0
    assert (out / PROGRAM_FILE).is_file()
    assert (out / CARD_FILE).is_file()
    test_csv = tmp_path / "test.csv"
    write_trace_csv(_trace("sine:0.02", 40.0, seed=7), test_csv)
    js = tmp_path / "eval.json"
    argv = ["evaluate", "nominal", "--model", str(out), "--data", str(test_csv), "--json", str(js)]
    assert cli.main(argv) == 0
    result = json.loads(js.read_text())
    assert set(result) == {"mode", "rpm_r2", "current_r2", "rpm_rmse", "current_rmse",
                           "init_window_s"}  # fmt: skip
    assert result["mode"] == "parallel"
    assert result["init_window_s"] == pytest.approx(2.0)
    assert result["rpm_r2"] > 0.5
    assert result["rpm_rmse"] > 0
    bad = ["evaluate", "nominal", "--model", str(tmp_path / "none"), "--data", str(test_csv)]
    assert cli.main(bad) == 2
    assert "model directory missing" in capsys.readouterr().err


def test_table2_smoke() -> None:
    cfg = ProtocolConfig(
        train_samples=600,
        test_samples=300,
        test_freqs=(0.01, 0.04),
        seeds=(0,),
        architectures=("narx",),
        sysidentpy=False,
        train=replace(FAST, epochs=15, finetune_epochs=3),
    )
    scores = run_table2(cfg)
    assert {(s.model, s.mode) for s in scores} == {
        ("narx", "parallel"),
        ("narx", "series-parallel"),
    }
    assert len(scores) == 4
    sp = {s.freq: s for s in scores if s.mode == "series-parallel"}
    assert sp[0.01].rpm_r2 > 0.9  # one step ahead is easy even after a short training
    table = table2_markdown(scores, cfg)
    assert "| paper NARX (Table 2) | ? | ? | 0.9745 | 0.6432 |" in table
    assert "| narx | parallel | 2 |" in table
