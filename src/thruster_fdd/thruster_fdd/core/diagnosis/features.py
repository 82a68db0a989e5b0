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
  rpm squared, rpm per command;
- ripple and spectrum: a broken blade adds a once-per-revolution ripple to the current and the
  speed, aliased at telemetry rates into broadband sample-to-sample noise: robust (MAD) spread of
  the first differences, absolute and relative, and the fraction of the detrended current's
  power above ``HF_HZ``.

A feature that a window cannot define (no turning samples, say) is NaN; the classifier replaces
it with its training median (``ClassifierModel``), so a quiet window looks typical, not extreme.
"""

from __future__ import annotations

import numpy as np
from numba import njit

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


# Number of features the compiled kernel makes: all but the last (``current_hf_fraction``).
_N_KERNEL = len(FEATURE_NAMES) - 1


@njit(cache=True)
def _mad(x: np.ndarray) -> float:
    """Robust standard deviation: 1.4826 x median absolute deviation; NaN when empty."""
    n = len(x)
    if n == 0:
        return np.nan
    m = n // 2
    s = np.sort(x)
    med = s[m] if n % 2 else (s[m - 1] + s[m]) / 2.0
    s = np.sort(np.abs(x - med))
    return _MAD_TO_STD * (s[m] if n % 2 else (s[m - 1] + s[m]) / 2.0)


@njit(cache=True)
def _kernel_features(w: np.ndarray) -> np.ndarray:
    """Every feature of ``window_features`` but the spectral one, compiled, from a
    C-contiguous window (n, 6).

    A window decision is on the diagnosis' latency path: compiled, these features cost a
    small fraction of their numpy form, which spends its time dispatching some hundred calls
    on 200-sample arrays (``bench/bench_classifier.py``). Written as loops over samples, which
    numba compiles in a fraction of the time array expressions take.
    """
    n = w.shape[0]
    # Ratio sums: numerator, denominator, count, for the 9 ratio features in output order.
    num = np.zeros(9)
    den = np.zeros(9)
    cnt = np.zeros(9)
    volt_sum = cmd_abs_sum = active_sum = 0.0
    res_rpm_sum = res_cur_sum = cur_abs_sum = rpm_abs_sum = 0.0
    for i in range(n):
        cmd, volt, rpm, cur, res_rpm, res_cur = w[i]
        pred_rpm = rpm - res_rpm
        speed = abs(pred_rpm)
        signed_res = res_rpm * np.sign(pred_rpm)
        cur_den = max(abs(cur - res_cur), 0.3)
        krpm = abs(rpm) / 1000.0
        volt_sum += volt
        cmd_abs_sum += abs(cmd)
        res_rpm_sum += res_rpm
        res_cur_sum += res_cur
        cur_abs_sum += abs(cur)
        rpm_abs_sum += abs(rpm)
        if speed >= ACTIVE_RPM:  # active, then low or high (HIGH_RPM > ACTIVE_RPM)
            active_sum += 1.0
            region = 1 if speed < HIGH_RPM else 2
            for j in (0, region):
                num[2 * j] += signed_res
                den[2 * j] += speed
                cnt[2 * j] += 1.0
                num[2 * j + 1] += res_cur
                den[2 * j + 1] += cur_den
                cnt[2 * j + 1] += 1.0
        if krpm >= ACTIVE_RPM / 1000.0:  # turning
            num[6] += volt * cur * krpm**3
            den[6] += krpm**6
            cnt[6] += 1.0
            num[7] += cur * krpm**2
            den[7] += krpm**4
            cnt[7] += 1.0
        if abs(cmd) >= 0.2:  # driven
            num[8] += krpm * abs(cmd)
            den[8] += cmd**2
            cnt[8] += 1.0
    res_rpm_mean = res_rpm_sum / n
    res_cur_mean = res_cur_sum / n
    var_rpm = var_cur = 0.0
    for i in range(n):
        var_rpm += (w[i, 4] - res_rpm_mean) ** 2
        var_cur += (w[i, 5] - res_cur_mean) ** 2
    d_cur = np.empty(n - 1)
    d_rpm = np.empty(n - 1)
    for i in range(n - 1):
        d_cur[i] = w[i + 1, 3] - w[i, 3]
        d_rpm[i] = w[i + 1, 2] - w[i, 2]
    current_ripple = _mad(d_cur) / np.sqrt(2.0)
    out = np.empty(_N_KERNEL)
    out[0] = volt_sum / n
    out[1] = cmd_abs_sum / n
    out[2] = active_sum / n
    out[3] = res_rpm_mean
    out[4] = np.sqrt(var_rpm / n)
    out[5] = res_cur_mean
    out[6] = np.sqrt(var_cur / n)
    for k in range(9):
        ok = cnt[k] >= MIN_REGION_SAMPLES and den[k] > 0
        out[7 + k] = num[k] / den[k] if ok else np.nan
    out[16] = current_ripple
    out[17] = current_ripple / (cur_abs_sum / n + 0.2)
    out[18] = _mad(d_rpm) / np.sqrt(2.0) / (rpm_abs_sum / n + 300.0)
    return out


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
    out = np.empty(len(FEATURE_NAMES))
    # Contiguous arrays only: one compiled variant per kernel, whatever layout came in.
    out[:_N_KERNEL] = _kernel_features(np.ascontiguousarray(w))
    out[_N_KERNEL] = _hf_fraction(np.ascontiguousarray(w[:, 3]), sample_time_s)
    return out


@njit(cache=True)
def _hf_fraction(x: np.ndarray, sample_time_s: float) -> float:
    """Fraction of the linearly detrended signal's power between LF_HZ and HF_HZ.. Nyquist that
    lies above HF_HZ; NaN when the band is empty or holds no more than rounding noise.

    Power is ``|rfft|**2`` per bin. Only the bins below HF_HZ are computed (a direct DFT over a
    table of twiddle factors); the band sums come from Parseval's sum over all bins. For a
    window of a few hundred samples that is several times faster than numpy's FFT call.
    """
    n = len(x)
    # Least-squares line through (i, x_i), closed form (what np.polyfit(i, x, 1) fits).
    t = np.arange(n) - (n - 1) / 2.0
    mean = x.mean()
    slope = np.sum(t * (x - mean)) / np.sum(t * t)
    d = x - mean - slope * t
    angle = 2.0 * np.pi * np.arange(n) / n
    cos, sin = np.cos(angle), np.sin(angle)
    df = 1.0 / (n * sample_time_s)
    n_bins = n // 2 + 1
    if (n_bins - 1) * df < HF_HZ:
        return np.nan
    # Parseval: the sum of |X_k|^2 over the one-sided bins 0..n//2.
    one_sided = n * np.sum(d * d) + np.sum(d) ** 2
    if n % 2 == 0:
        one_sided += np.sum(d[::2] - d[1::2]) ** 2
    one_sided /= 2.0
    below_lf = 0.0
    below_hf = 0.0
    k = 0
    while k * df < HF_HZ:
        re = 0.0
        im = 0.0
        m = 0  # (k * i) mod n
        for i in range(n):
            re += d[i] * cos[m]
            im -= d[i] * sin[m]
            m += k
            if m >= n:
                m -= n
        power = re * re + im * im
        below_hf += power
        if k * df < LF_HZ:
            below_lf += power
        k += 1
    total = one_sided - below_lf
    # A constant window leaves only rounding noise after detrending: no spectrum to speak of.
    if total <= 1e-20 * n * (np.sum(x * x) + 1e-300):
        return np.nan
    return max(one_sided - below_hf, 0.0) / total
