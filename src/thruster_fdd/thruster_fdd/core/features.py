"""Window features for fault diagnosis: what a voltage drop, a broken blade or fouling does.

A window is a run of consecutive valid residual samples at the nominal model's sample time
(command, bus voltage, measured rpm and current, and the residuals measured - predicted of the
nominal model). ``window_features`` turns it into one vector of ``FEATURE_NAMES``:

- operating point: mean bus voltage (it alone separates the three nominal supplies, which the
  nominal model takes as an input and so leaves with alike residuals), mean |command|, and the
  fraction of samples where the rotor turns;
- residual statistics: mean and std of both residuals, and the residuals relative to the
  prediction (a fouled rotor turns slower on more current at every speed, a broken blade faster
  on less) over all turning samples and per operating region (below / above ``HIGH_RPM``);
- steady-state ratios: electric power per speed cubed (``V I / w^3`` is proportional to the
  propeller torque coefficient k_q, which fouling raises and broken blades lower), current per
  rpm squared (the issue's ratio), rpm per command;
- ripple and spectrum: a broken blade adds a once-per-revolution ripple to the current and the
  speed, aliased at telemetry rates into broadband sample-to-sample noise: robust (MAD) spread of
  the first differences, absolute and relative, and the fraction of the detrended current's
  power above ``HF_HZ``.

A feature that a window cannot define (no turning samples, say) is NaN; the classifier replaces
it with its training median (``ClassifierModel``), so a quiet window looks typical, not extreme.
"""

from __future__ import annotations

import numpy as np

FEATURE_NAMES: tuple[str, ...] = (
    "voltage_mean",
    "command_abs_mean",
    "active_fraction",
    "res_rpm_mean",
    "res_rpm_std",
    "res_current_mean",
    "res_current_std",
    "rel_res_rpm",
    "rel_res_current",
    "rel_res_rpm_low",
    "rel_res_current_low",
    "rel_res_rpm_high",
    "rel_res_current_high",
    "power_per_speed3",
    "current_per_rpm2",
    "rpm_per_command",
    "current_ripple",
    "current_ripple_rel",
    "rpm_ripple_rel",
    "current_hf_fraction",
)
"""Feature order of ``window_features`` (and of the classifier's input)."""

WINDOW_SIGNALS: tuple[str, ...] = (
    "command",
    "voltage",
    "rpm",
    "current",
    "residual_rpm",
    "residual_current",
)
"""Per-sample inputs of a window, in column order: -1..1, V, rpm, A, rpm, A."""

ACTIVE_RPM = 600.0
"""|rpm| (predicted) above which a sample counts as turning (twice the T100's 300 rpm floor)."""

HIGH_RPM = 2000.0
"""Border between the low and high operating regions, |rpm|."""

MIN_REGION_SAMPLES = 10
"""Fewest samples a region or ratio needs; fewer give NaN."""

HF_HZ = 2.0
"""Lower edge of the 'high frequency' band of ``current_hf_fraction``, Hz."""

LF_HZ = 0.2
"""Frequencies below this (the command's own motion) are left out of the spectral ratio, Hz."""

_MAD_TO_STD = 1.4826


def _median(x: np.ndarray) -> float:
    """``np.median`` of a 1-D array without NaN, at a fraction of its cost on short arrays."""
    s = np.sort(x)
    m = len(s) // 2
    return float(s[m]) if len(s) % 2 else float((s[m - 1] + s[m]) / 2.0)


def _mad(x: np.ndarray) -> float:
    """Robust standard deviation: 1.4826 x median absolute deviation."""
    return _MAD_TO_STD * _median(np.abs(x - _median(x))) if len(x) else float("nan")


def _ratio(num: np.ndarray, den: np.ndarray, mask: np.ndarray) -> float:
    """``sum(num[mask]) / sum(den[mask])``; NaN with fewer than MIN_REGION_SAMPLES in mask."""
    if int(mask.sum()) < MIN_REGION_SAMPLES:
        return float("nan")
    d = float(den[mask].sum())
    return float(num[mask].sum()) / d if d > 0 else float("nan")


def window_features(window: np.ndarray, sample_time_s: float) -> np.ndarray:
    """Feature vector of one window.

    Parameters
    ----------
    window : np.ndarray, shape (n, 6)
        Consecutive valid samples, columns ``WINDOW_SIGNALS``: command (-1..1), bus voltage (V),
        measured rpm, measured current (A), residual rpm, residual current (A); n >= 4.
    sample_time_s : float
        Time between samples, s (the nominal model's sample time).

    Returns
    -------
    np.ndarray, shape (len(FEATURE_NAMES),)
        Features in ``FEATURE_NAMES`` order; NaN where the window cannot define one. Units:
        V, -, -, rpm, rpm, A, A, -, -, -, -, -, -, W / krpm^3, A / krpm^2, krpm, A, -, -, -.

    Raises
    ------
    ValueError
        If the shape is wrong, a value is not finite, or the sample time is not positive.
    """
    w = np.asarray(window, dtype=float)
    if w.ndim != 2 or w.shape[1] != len(WINDOW_SIGNALS) or len(w) < 4:
        raise ValueError(f"window must have shape (n >= 4, {len(WINDOW_SIGNALS)}), got {w.shape}")
    if not np.all(np.isfinite(w)):
        raise ValueError("window holds non-finite values")
    if not sample_time_s > 0:
        raise ValueError(f"sample_time_s must be > 0, got {sample_time_s}")
    cmd, volt, rpm, cur, res_rpm, res_cur = w.T
    pred_rpm = rpm - res_rpm
    pred_cur = cur - res_cur
    speed = np.abs(pred_rpm)
    active = speed >= ACTIVE_RPM
    low = active & (speed < HIGH_RPM)
    high = speed >= HIGH_RPM
    signed_res = res_rpm * np.sign(pred_rpm)
    cur_den = np.maximum(np.abs(pred_cur), 0.3)
    krpm = np.abs(rpm) / 1000.0
    turning = krpm >= ACTIVE_RPM / 1000.0
    driven = np.abs(cmd) >= 0.2
    d_cur = np.diff(cur)
    d_rpm = np.diff(rpm)
    current_ripple = _mad(d_cur) / np.sqrt(2.0)
    features = [
        float(volt.mean()),
        float(np.abs(cmd).mean()),
        float(active.mean()),
        float(res_rpm.mean()),
        float(res_rpm.std()),
        float(res_cur.mean()),
        float(res_cur.std()),
        _ratio(signed_res, speed, active),
        _ratio(res_cur, cur_den, active),
        _ratio(signed_res, speed, low),
        _ratio(res_cur, cur_den, low),
        _ratio(signed_res, speed, high),
        _ratio(res_cur, cur_den, high),
        _ratio(volt * cur * krpm**3, krpm**6, turning),
        _ratio(cur * krpm**2, krpm**4, turning),
        _ratio(krpm * np.abs(cmd), cmd**2, driven),
        current_ripple,
        current_ripple / (float(np.abs(cur).mean()) + 0.2),
        _mad(d_rpm) / np.sqrt(2.0) / (float(np.abs(rpm).mean()) + 300.0),
        _hf_fraction(cur, sample_time_s),
    ]
    return np.asarray(features, dtype=float)


def _hf_fraction(x: np.ndarray, sample_time_s: float) -> float:
    """Fraction of the linearly detrended signal's power between LF_HZ and HF_HZ.. Nyquist that
    lies above HF_HZ; NaN when the band is empty or the signal has no power there."""
    n = len(x)
    # Least-squares line through (i, x_i), closed form (what np.polyfit(i, x, 1) fits).
    t = np.arange(n) - (n - 1) / 2.0
    slope = float(t @ (x - x.mean())) / float(t @ t)
    detrended = x - x.mean() - slope * t
    power = np.abs(np.fft.rfft(detrended)) ** 2
    freq = np.fft.rfftfreq(n, sample_time_s)
    total = float(power[freq >= LF_HZ].sum())
    high = freq >= HF_HZ
    if not high.any() or total <= 0:
        return float("nan")
    return float(power[high].sum()) / total
