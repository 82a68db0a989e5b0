"""Fit the ``t200`` simulator preset to Blue Robotics' T200 bollard measurements.

Reads ``<data>/<V>_V.csv`` (steady rpm and current against PWM at 10-20 V), fits the static
motor/ESC/propeller parameters with scipy (Nelder-Mead on the worst per-voltage median error),
the thrust coefficients by least squares, writes the preset YAML and a Markdown error table.

Usage::

    python scripts/calibrate_t200.py [--data ../shared/data/t200] [--out PRESET.yaml]
                                     [--table out/t200_fit.md]
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from thruster_fdd_shore.core.sim.config import Measurement, SimConfig, ThrusterParams, dump_config
from thruster_fdd_shore.core.sim.effects import Deadband, EscLag
from thruster_fdd_shore.core.sim.plant import RAD_S_TO_RPM
from thruster_fdd_shore.core.sim.steady import steady_state

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "t200"
DEFAULT_OUT = (
    REPO
    / "src"
    / "thruster_fdd_shore"
    / "thruster_fdd_shore"
    / "core"
    / "sim"
    / "presets"
    / "t200.yaml"
)
DEFAULT_TABLE = REPO / "out" / "t200_fit.md"
KGF_TO_N = 9.80665

# Fitted parameters, in order, and the starting point (a previous fit; refined on every run).
FIT_NAMES = ("k_e", "r_ohm", "r_speed_ohm_s", "k_q", "k_q_reverse_ratio", "width", "esc_v_sat_v")
FIT_START = (0.019065, 0.10826, 5.738e-4, 3.9545e-6, 0.98723, 0.033963, 72.61)


@dataclass(frozen=True)
class Sheet:
    """One voltage sheet: arrays of shape (201,)."""

    voltage: float
    pwm_us: np.ndarray
    rpm: np.ndarray
    current: np.ndarray
    force_n: np.ndarray


@dataclass(frozen=True)
class SheetErrors:
    """Fit errors at one voltage (% of the sheet's full scale) and zero-band edges (us)."""

    voltage: float
    rpm_median: float
    rpm_max: float
    current_median: float
    current_max: float
    band_data: tuple[float, float]
    band_model: tuple[float, float]

    @property
    def band_error_us(self) -> float:
        """Largest difference between data and model zero-band edges, us."""
        return max(abs(a - b) for a, b in zip(self.band_data, self.band_model, strict=False))


def load_sheets(folder: Path) -> list[Sheet]:
    """Read every ``*_V.csv`` of the T200 workbook (headers with leading spaces, stray commas)."""
    files = sorted(folder.glob("*_V.csv"), key=lambda p: float(p.stem.split("_")[0]))
    if not files:
        raise ValueError(f"no T200 sheets (*_V.csv) in {folder}")
    sheets = []
    for path in files:
        with path.open(encoding="utf-8") as f:
            rows = list(csv.reader(f))
        header = [h.strip() for h in rows[0]]
        col = {name: header.index(name) for name in ("PWM (µs)", "RPM", "Current (A)")}
        v_col, f_col = header.index("Voltage (V)"), header.index("Force (Kg f)")
        values = np.array(
            [
                [float(r[col["PWM (µs)"]]), float(r[col["RPM"]]), float(r[col["Current (A)"]]),
                 float(r[v_col]), float(r[f_col])]
                for r in rows[1:]
                if r and r[0].strip()
            ]
        )  # fmt: skip
        sheets.append(
            Sheet(
                voltage=float(values[0, 3]),
                pwm_us=values[:, 0],
                rpm=values[:, 1],
                current=values[:, 2],
                force_n=values[:, 4] * KGF_TO_N,
            )
        )
    return sheets


def zero_band(pwm_us: np.ndarray, rpm: np.ndarray) -> tuple[float, float]:
    """Lowest and highest PWM of the run of zero speed that contains (or is nearest) 1500 us."""
    zero = rpm == 0.0
    if not zero.any():
        return (1500.0, 1500.0)
    i = int(np.argmin(np.abs(pwm_us - 1500.0) + np.where(zero, 0.0, 1e9)))
    lo = hi = i
    while lo > 0 and zero[lo - 1]:
        lo -= 1
    while hi < len(zero) - 1 and zero[hi + 1]:
        hi += 1
    return (float(pwm_us[lo]), float(pwm_us[hi]))


def sheet_errors(config: SimConfig, sheet: Sheet) -> SheetErrors:
    """Compare the configuration's reported steady curves with one sheet (|rpm| compared)."""
    command = (sheet.pwm_us - 1500.0) / 400.0
    rpm, current = steady_state(config, command, sheet.voltage, reported=True)
    rpm = np.abs(rpm)
    e_rpm = np.abs(rpm - sheet.rpm) / sheet.rpm.max() * 100.0
    e_cur = np.abs(current - sheet.current) / sheet.current.max() * 100.0
    return SheetErrors(
        voltage=sheet.voltage,
        rpm_median=float(np.median(e_rpm)),
        rpm_max=float(e_rpm.max()),
        current_median=float(np.median(e_cur)),
        current_max=float(e_cur.max()),
        band_data=zero_band(sheet.pwm_us, sheet.rpm),
        band_model=zero_band(sheet.pwm_us, rpm),
    )


def template() -> SimConfig:
    """The t200 preset before fitting: dynamics and measurement are assumed, not calibrated."""
    params = ThrusterParams(
        k_e=FIT_START[0],
        r_ohm=FIT_START[1],
        r_speed_ohm_s=FIT_START[2],
        esc_v_sat_v=FIT_START[6],
        inertia=1.2e-4,
        k_q=FIT_START[3],
        k_q_reverse_ratio=FIT_START[4],
        k_thrust=1.0e-4,
        reverse_thrust_ratio=0.8,
        i_idle_a=0.02,
        water_temp_c=15.0,
        thermal_resistance_c_per_w=0.3,
        thermal_tau_s=60.0,
    )
    measurement = Measurement(
        rpm_noise=15.0,
        current_noise_a=0.05,
        voltage_noise_v=0.02,
        rpm_step=1.0,
        current_step_a=0.01,
        voltage_step_v=0.01,
        outlier_prob=0.001,
        outlier_rpm=500.0,
        outlier_current_a=2.0,
        outlier_voltage_v=0.5,
        rpm_floor=300.0,
        floor_zeroes_current=True,
    )
    effects = (Deadband(width=FIT_START[5]), EscLag(tau_s=0.1))
    return SimConfig("t200", params, effects, measurement, spread=0.03)


def with_fit(config: SimConfig, values: np.ndarray) -> SimConfig:
    """Return ``config`` with the ``FIT_NAMES`` values set."""
    named = dict(zip(FIT_NAMES, (float(v) for v in values), strict=False))
    width = named.pop("width")
    params = replace(config.params, **named)
    effects = tuple(Deadband(width=width) if e.name == "deadband" else e for e in config.effects)
    return replace(config, params=params, effects=effects)


def objective(config: SimConfig, sheets: list[Sheet]) -> float:
    """Worst per-voltage median error, plus smaller terms for the mean and the band edges."""
    errors = [sheet_errors(config, s) for s in sheets]
    medians = np.array([[e.rpm_median, e.current_median] for e in errors])
    maxima = np.array([[e.rpm_max, e.current_max] for e in errors])
    band = max(e.band_error_us for e in errors)
    return float(
        medians.max() + 0.5 * medians.mean() + 0.05 * maxima.mean() + 0.5 * max(0, band - 4)
    )


def fit(sheets: list[Sheet], *, restarts: int = 3) -> SimConfig:
    """Fit the static parameters, then the thrust coefficients, starting from ``template()``."""
    base = template()
    start = np.array(FIT_START)

    def cost(q: np.ndarray) -> float:
        values = start * np.exp(q)
        if values[FIT_NAMES.index("width")] >= 0.5:
            return 1e6
        return objective(with_fit(base, values), sheets)

    q = np.zeros(len(start))
    for _ in range(restarts):
        q = minimize(cost, q, method="Nelder-Mead", options={"maxiter": 1500, "adaptive": True}).x
    config = with_fit(base, start * np.exp(q))
    return fit_thrust(config, sheets)


def fit_thrust(config: SimConfig, sheets: list[Sheet]) -> SimConfig:
    """Least-squares thrust coefficients (forward and reverse) from measured force and rpm."""
    w2 = np.concatenate([(s.rpm / RAD_S_TO_RPM) ** 2 for s in sheets])
    force = np.concatenate([s.force_n for s in sheets])
    reverse = np.concatenate([s.pwm_us < 1500 for s in sheets])
    fwd = (~reverse) & (w2 > 0)
    rev = reverse & (w2 > 0)
    k_fwd = float(np.sum(force[fwd] * w2[fwd]) / np.sum(w2[fwd] ** 2))
    k_rev = float(-np.sum(force[rev] * w2[rev]) / np.sum(w2[rev] ** 2))
    params = replace(config.params, k_thrust=k_fwd, reverse_thrust_ratio=k_rev / k_fwd)
    return replace(config, params=params)


def markdown_table(errors: list[SheetErrors]) -> str:
    """Per-voltage error table (Markdown)."""
    lines = [
        "| supply V | rpm median % FS | rpm max % FS | current median % FS | current max % FS "
        "| zero band data (us) | zero band model (us) |",
        "|---|---|---|---|---|---|---|",
    ]
    for e in errors:
        lines.append(
            f"| {e.voltage:g} | {e.rpm_median:.2f} | {e.rpm_max:.2f} | {e.current_median:.2f} "
            f"| {e.current_max:.2f} | {e.band_data[0]:.0f}-{e.band_data[1]:.0f} "
            f"| {e.band_model[0]:.0f}-{e.band_model[1]:.0f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder of *_V.csv")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="preset YAML to write")
    parser.add_argument("--table", type=Path, default=DEFAULT_TABLE, help="Markdown table to write")
    parser.add_argument("--restarts", type=int, default=3, help="Nelder-Mead restarts")
    args = parser.parse_args(argv)
    try:
        sheets = load_sheets(args.data)
    except (OSError, ValueError) as exc:
        print(f"calibrate_t200: {exc}", file=sys.stderr)
        return 2
    config = fit(sheets, restarts=args.restarts)
    dump_config(config, args.out)
    table = markdown_table([sheet_errors(config, s) for s in sheets])
    args.table.parent.mkdir(parents=True, exist_ok=True)
    args.table.write_text(table)
    print(table, end="")
    fitted = {n: getattr(config.params, n, None) for n in FIT_NAMES if n != "width"}
    fitted["width"] = config.effect("deadband").width  # type: ignore[union-attr]
    print("fitted:", ", ".join(f"{k}={v:.6g}" for k, v in fitted.items() if not math.isnan(v)))
    print(f"wrote {args.out} and {args.table}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
