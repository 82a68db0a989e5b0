"""Where a model disagrees with a measurement: the held-out gap (``gap``), the share of the
squared residual in each operating region (``regions``) and the cues that point to causes
(``signatures``: lag, flat zone, clipping, offsets growing with current), read out in plain
words by ``describe``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thruster_fdd_shore.core.discrepancy.measure import (
    CHANNELS,
    Measured,
    _uncensored,
    reported,
    weighted_residuals,
)

TRANSIENT_S = 3.0
"""Samples within this time after a command change count as transient, s."""


def gap(sim: dict[str, np.ndarray], data: Measured) -> dict[str, float]:
    """Gap between a simulation and the measurement on the held-out samples: ``rpm_rmse``,
    ``current_rmse`` (rpm, A, the model reported as the telemetry would be), ``rpm_r2``,
    ``current_r2`` (coefficient of determination) and ``score``: the mean over channels of the
    mean squared residual, in noise variances, over the samples the reporting floor leaves
    informative (a censored sample's residual is the model's excess over the floor)."""
    held, rep = data.held, reported(sim, data)
    res, seen = weighted_residuals(sim, data), _uncensored(data)
    out = {}
    for c in ("rpm", "current"):
        y, e = data.channel(c)[held], (data.channel(c) - rep[c])[held]
        ss = float(np.sum((y - y.mean()) ** 2))
        out[f"{c}_rmse"] = float(np.sqrt(np.mean(e**2)))
        out[f"{c}_r2"] = 1.0 - float(np.sum(e**2)) / ss if ss > 0.0 else float("nan")
    out["score"] = float(
        np.mean(
            [
                np.sum(res[c][held] ** 2) / max(int(np.sum(seen[c][held])), 1) / data.sigma[c] ** 2
                for c in CHANNELS
            ]
        )
    )
    return out


@dataclass(frozen=True)
class Region:
    """Share of one signal's squared residual that lies in one operating region.

    Attributes
    ----------
    signal : str
        ``rpm`` or ``current``.
    region : str
        Region description.
    error_share : float
        Fraction of the signal's squared residual inside the region.
    sample_share : float
        Fraction of the samples inside the region.
    rmse : float
        RMSE inside the region (rpm or A).
    """

    signal: str
    region: str
    error_share: float
    sample_share: float
    rmse: float


def region_masks(data: Measured) -> dict[str, np.ndarray]:
    """Boolean masks, shape (n,), of the operating regions used by ``regions``."""
    mag = np.abs(data.command)
    change = np.flatnonzero(np.abs(np.diff(data.command)) > 0.02) + 1
    last = np.full(len(data.t), -np.inf)
    last[0] = data.t[0]
    last[change] = data.t[change]
    since = data.t - np.maximum.accumulate(last)
    high_i = np.quantile(data.current, 0.9)
    return {
        "|command| < 0.1 (near zero)": mag < 0.1,
        "0.1 <= |command| < 0.4": (mag >= 0.1) & (mag < 0.4),
        "0.4 <= |command| < 0.7": (mag >= 0.4) & (mag < 0.7),
        "|command| >= 0.7": mag >= 0.7,
        "reverse (command < 0)": data.command < 0.0,
        f"transient (< {TRANSIENT_S:g} s after a command change)": since < TRANSIENT_S,
        f"steady (>= {TRANSIENT_S:g} s after a command change)": since >= TRANSIENT_S,
        f"high current (top 10 %, >= {high_i:.2f} A)": data.current >= high_i,
    }


def regions(sim: dict[str, np.ndarray], data: Measured, mask: np.ndarray) -> list[Region]:
    """Split the squared residuals of rpm and current over ``region_masks`` within ``mask``.

    Returns
    -------
    list of Region
        For each signal, every region, sorted by error share (largest first).
    """
    res = weighted_residuals(sim, data)
    out = []
    for signal in ("rpm", "current"):
        sq = res[signal] ** 2
        total = float(sq[mask].sum()) or 1.0
        rows = []
        for name, region in region_masks(data).items():
            sel = region & mask
            if not sel.any():
                continue
            rows.append(
                Region(
                    signal=signal,
                    region=name,
                    error_share=float(sq[sel].sum()) / total,
                    sample_share=float(sel.sum()) / float(mask.sum()),
                    rmse=float(np.sqrt(sq[sel].mean())),
                )
            )
        out += sorted(rows, key=lambda r: -r.error_share)
    return out


def _lag_s(data: Measured, sim: dict[str, np.ndarray], max_lag_s: float = 3.0) -> float:
    """Delay of the measured speed behind the model's, s (cross-correlation of increments)."""
    a = np.diff(data.rpm)
    b = np.diff(reported(sim, data)["rpm"])
    dt = float(np.median(np.diff(data.t)))
    lags = range(-int(max_lag_s / dt), int(max_lag_s / dt) + 1)
    scores = []
    for k in lags:
        x, y = (a[k:], b[: len(b) - k]) if k >= 0 else (a[:k], b[-k:])
        scores.append(float(np.dot(x, y)))
    return float(list(lags)[int(np.argmax(scores))] * dt)


def _slope(x: np.ndarray, y: np.ndarray) -> float:
    if np.ptp(x) <= 0.0:
        return 0.0
    return float(np.polyfit(x, y, 1)[0])


def signatures(sim: dict[str, np.ndarray], data: Measured) -> dict[str, float]:
    """Cues of the residual of one simulation against the measurement (all samples).

    Returns
    -------
    dict of str to float
        ``lag_s`` (measured speed behind the model, s), ``zero_band_measured`` and
        ``zero_band_model`` (largest steady |command| with speed reported 0),
        ``current_max_measured`` and ``current_max_model`` (A, 99.5 % quantile; a lower
        measured maximum means clipping),
        ``current_residual_per_a`` (slope of current residual against measured current, A/A),
        ``voltage_residual_per_a`` (slope of bus-voltage residual against current, V/A; negative
        means an unmodelled voltage sag), ``steady_share_rpm`` (share of the rpm squared
        residual in steady state).
    """
    rep = reported(sim, data)
    masks = region_masks(data)
    steady = next(m for k, m in masks.items() if k.startswith("steady"))
    mag = np.abs(data.command)

    def band(rpm: np.ndarray) -> float:
        zero = steady & (rpm == 0.0)
        return float(mag[zero].max()) if zero.any() else 0.0

    res = weighted_residuals(sim, data)
    sq = res["rpm"] ** 2
    return {
        "lag_s": _lag_s(data, sim),
        "zero_band_measured": band(data.rpm),
        "zero_band_model": band(rep["rpm"]),
        "current_max_measured": float(np.quantile(data.current, 0.995)),
        "current_max_model": float(np.quantile(rep["current"], 0.995)),
        "current_residual_per_a": _slope(data.current, res["current"]),
        "voltage_residual_per_a": _slope(data.current, res["voltage"]),
        "steady_share_rpm": float(sq[steady].sum() / max(sq.sum(), 1e-300)),
    }


def describe(sig: dict[str, float]) -> list[str]:
    """Plain-language reading of ``signatures`` (one line per notable cue)."""
    lines = []
    if abs(sig["lag_s"]) >= 0.1:
        lines.append(
            f"the measured speed lags the model by {sig['lag_s']:.2f} s "
            "(cross-correlation of speed increments): a delay or lag is missing"
        )
    if sig["zero_band_measured"] - sig["zero_band_model"] >= 0.01:
        lines.append(
            f"flat zone: speed stays 0 up to |command| {sig['zero_band_measured']:.3f} measured, "
            f"{sig['zero_band_model']:.3f} in the model (deadband or static friction)"
        )
    if sig["current_max_model"] > 1.03 * sig["current_max_measured"]:
        lines.append(
            f"clipping: measured current tops out at {sig['current_max_measured']:.2f} A, "
            f"the model reaches {sig['current_max_model']:.2f} A (current limit)"
        )
    if abs(sig["current_residual_per_a"]) >= 0.02:
        lines.append(
            f"current offset grows with current: {sig['current_residual_per_a']:+.3f} A "
            "per A of measured current"
        )
    if sig["voltage_residual_per_a"] <= -0.005:
        lines.append(
            f"bus voltage falls {-sig['voltage_residual_per_a']:.3f} V per A more than "
            "the model's (supply resistance, voltage sag)"
        )
    return lines or ["no notable cue: the residual is close to noise"]
