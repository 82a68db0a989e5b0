"""The compiled window features and decision kernels equal their plain numpy definitions."""

from __future__ import annotations

import numpy as np
import pytest

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.core.diagnosis.features import (
    ACTIVE_RPM,
    FEATURE_NAMES,
    HF_HZ,
    HIGH_RPM,
    LF_HZ,
    MIN_REGION_SAMPLES,
    window_features,
)
from thruster_fdd.core.diagnosis.model import P_MIN, Z_CLIP, ClassifierModel
from thruster_fdd_shore.core.sim.scenario import run_scenario


def _mad(x: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if len(x) else float("nan")


def _ratio(num: np.ndarray, den: np.ndarray, mask: np.ndarray) -> float:
    if int(mask.sum()) < MIN_REGION_SAMPLES:
        return float("nan")
    d = float(den[mask].sum())
    return float(num[mask].sum()) / d if d > 0 else float("nan")


def _hf_fraction(x: np.ndarray, dt: float) -> float:
    t = np.arange(len(x)) - (len(x) - 1) / 2.0
    detrended = x - x.mean() - np.polyfit(t, x, 1)[0] * t
    power = np.abs(np.fft.rfft(detrended)) ** 2
    freq = np.fft.rfftfreq(len(x), dt)
    total = float(power[freq >= LF_HZ].sum())
    high = freq >= HF_HZ
    if not high.any() or total <= 1e-20 * len(x) * float(x @ x):
        return float("nan")
    return float(power[high].sum()) / total


def reference_features(w: np.ndarray, dt: float) -> np.ndarray:
    """``window_features`` written as the module docstring reads, in plain numpy."""
    cmd, volt, rpm, cur, res_rpm, res_cur = w.T
    pred_rpm, pred_cur = rpm - res_rpm, cur - res_cur
    speed = np.abs(pred_rpm)
    active = speed >= ACTIVE_RPM
    low, high = active & (speed < HIGH_RPM), speed >= HIGH_RPM
    signed_res = res_rpm * np.sign(pred_rpm)
    cur_den = np.maximum(np.abs(pred_cur), 0.3)
    krpm = np.abs(rpm) / 1000.0
    turning = krpm >= ACTIVE_RPM / 1000.0
    ripple = _mad(np.diff(cur)) / np.sqrt(2.0)
    return np.array(
        [
            volt.mean(),
            np.abs(cmd).mean(),
            active.mean(),
            res_rpm.mean(),
            res_rpm.std(),
            res_cur.mean(),
            res_cur.std(),
            _ratio(signed_res, speed, active),
            _ratio(res_cur, cur_den, active),
            _ratio(signed_res, speed, low),
            _ratio(res_cur, cur_den, low),
            _ratio(signed_res, speed, high),
            _ratio(res_cur, cur_den, high),
            _ratio(volt * cur * krpm**3, krpm**6, turning),
            _ratio(cur * krpm**2, krpm**4, turning),
            _ratio(krpm * np.abs(cmd), cmd**2, np.abs(cmd) >= 0.2),
            ripple,
            ripple / (np.abs(cur).mean() + 0.2),
            _mad(np.diff(rpm)) / np.sqrt(2.0) / (np.abs(rpm).mean() + 300.0),
            _hf_fraction(cur, dt),
        ]
    )


@pytest.mark.parametrize("condition", ["nominal_15v", "broken_blade_2", "biofouling"])
def test_compiled_features_equal_the_numpy_definition(condition: str) -> None:
    tr = run_scenario("t100", condition, signal="mission", duration_s=240.0, seed=5)
    rng = np.random.default_rng(0)
    res = np.stack([rng.normal(0, 50, len(tr)), rng.normal(0, 0.2, len(tr))], axis=1)
    w = np.column_stack([tr.command, tr.voltage, tr.rpm, tr.current, res])
    idle = np.tile([0.0, 15.0, 0.0, 0.05, 0.0, 0.0], (60, 1))
    windows = [w[s : s + n] for s in range(0, len(w) - 200, 53) for n in (200, 41, 39, 4)]
    windows += [idle, w[::2][:100]]  # a constant window; a strided (non-contiguous) one
    for win in windows:
        got, want = window_features(win, 0.1), reference_features(win, 0.1)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12, equal_nan=True)


def test_compiled_decision_equals_the_numpy_definition() -> None:
    model = ClassifierModel.load(default_models_dir() / "classifier")
    rng = np.random.default_rng(1)
    n = len(FEATURE_NAMES)
    x = model._center + model._scale * rng.normal(scale=3.0, size=(64, n))
    x[::5, 7] = np.nan
    probs, dist = model.predict_proba(x)
    filled = np.where(np.isnan(x), model._fill, x)
    h = np.clip((filled - model._center) / model._scale, -Z_CLIP, Z_CLIP)
    for k, (weight, bias) in enumerate(model._layers):
        h = h @ weight.T + bias
        h = np.maximum(h, 0.0) if k < len(model._layers) - 1 else h
    n_classes = h.shape[1]
    e = np.exp(h / model.card.temperature - (h / model.card.temperature).max(1, keepdims=True))
    # The definition: the tempered softmax, moved into [P_MIN, 1 - P_MIN] (``bounded``).
    want_p = P_MIN + (1.0 - n_classes * P_MIN) * e / e.sum(1, keepdims=True)
    np.testing.assert_allclose(probs, want_p, rtol=1e-9, atol=1e-12)
    z = (filled - model._center) / model._scale
    _, _, mean, std = model._distance_args
    want = np.sqrt((((z[:, None] - mean[None]) / std[None]) ** 2).mean(axis=2)).min(axis=1)
    np.testing.assert_allclose(dist, want, rtol=1e-9)
