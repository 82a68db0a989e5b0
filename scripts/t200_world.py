"""Trace CSVs from a thruster world made independently of the project's simulator.

Static maps rpm(command, V) and current(command, V) interpolated from the real T200 workbook
(../shared/data/t200), a first-order rotor lag, an acceleration current, unit-to-unit spread of
gains and lag, supply sag with current, sensor noise; faults change the propeller load (rpm and
current factors) and add a once-per-revolution current ripple. Nothing here imports the
simulator, so models trained on these traces meet thrusters the project did not build.

Usage::

    python scripts/t200_world.py paper --out DIR     # 3 units, 0.01 Hz sine, 200 s per class
    python scripts/t200_world.py rich --out DIR      # 6 units, sine + steps + patrol per class
    python scripts/t200_world.py healthy --out DIR --first-seed 100 --runs 6 --seconds 3600
    python scripts/t200_world.py faulty --out DIR --first-seed 200 --runs 12 --seconds 1200
"""

from __future__ import annotations

import argparse
import csv
import functools
import math
import sys
import zlib
from pathlib import Path

import numpy as np
from scipy.interpolate import RegularGridInterpolator

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "t200"
RATE = 10.0


@functools.cache
def maps() -> tuple[RegularGridInterpolator, RegularGridInterpolator]:
    """rpm and current (A) over (command -1..1, supply V) from the workbook's sheets."""
    volts = [10, 12, 14, 16, 18, 20]
    rows = [
        np.loadtxt(DATA / f"{v}_V.csv", delimiter=",", skiprows=1, usecols=range(7)) for v in volts
    ]
    pwm = rows[0][:, 0]
    rpm = np.stack([r[:, 1] * np.sign(r[:, 0] - 1500) for r in rows], axis=1)
    cur = np.stack([r[:, 2] for r in rows], axis=1)
    cmd = (pwm - 1500) / 400
    return (
        RegularGridInterpolator((cmd, np.array(volts, float)), rpm),
        RegularGridInterpolator((cmd, np.array(volts, float)), cur),
    )


FAULTS = {  # rpm factor, current factor, ripple amplitude (share of current)
    "broken_blade_1": (1.05, 0.82, 0.10),
    "broken_blade_2": (1.10, 0.66, 0.16),
    "biofouling": (0.93, 1.14, 0.02),
}


def unit(seed: int) -> dict[str, float]:
    """A unit's spread: rpm and current gains, rotor lag (s), supply sag (ohm), accel. current."""
    r = np.random.default_rng(10_000 + seed)
    return dict(
        g=1 + 0.03 * r.standard_normal(),
        h=1 + 0.05 * r.standard_normal(),
        tau=0.18 * (1 + 0.2 * r.standard_normal()),
        sag=0.06 + 0.02 * r.random(),
        kacc=0.0004 * (1 + 0.3 * r.random()),
    )


def simulate(
    cmd: np.ndarray, supply: np.ndarray, condition: str, seed: int, noise_seed: int,
    fault_at: float | None = None, fault: str | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """rpm, current (A) and bus voltage (V) at RATE for commands (n,) and a supply (n,), V."""
    rpm_map, cur_map = maps()
    u = unit(seed)
    rng = np.random.default_rng(noise_seed)
    n = len(cmd)
    dt = 1 / RATE
    sub = 10
    h = dt / sub
    ce = 0.0
    phase = 0.0
    prev_rpm = 0.0
    out_rpm = np.empty(n)
    out_cur = np.empty(n)
    out_v = np.empty(n)
    cur_prev = 0.5
    for i in range(n):
        cond = condition if (fault_at is None or i * dt < fault_at) else fault
        rf, cf, rip = FAULTS.get(cond, (1.0, 1.0, 0.0))
        for _ in range(sub):
            ce += (cmd[i] - ce) * h / u["tau"]
        v = supply[i] - u["sag"] * cur_prev
        v = float(np.clip(v, 10.0, 20.0))
        c = float(np.clip(ce, -1, 1))
        rpm = float(rpm_map((c, v))) * u["g"] * rf
        acc = (rpm - prev_rpm) / dt
        cur = float(cur_map((c, v))) * u["h"] * cf + u["kacc"] * abs(acc) * 0.01 * abs(rpm) / 1000
        phase += abs(rpm) / 60 * 2 * math.pi * dt
        cur *= 1 + rip * math.sin(phase + rng.uniform(0, 0.3))
        cur += 0.15  # idle electronics
        prev_rpm = rpm
        cur_prev = cur
        out_rpm[i] = rpm + rng.normal(0, 12 + 0.004 * abs(rpm))
        out_cur[i] = max(cur + rng.normal(0, 0.04 + 0.015 * cur), 0.0)
        out_v[i] = v + rng.normal(0, 0.02)
    return out_rpm, out_cur, out_v


def sine(duration: float, f: float = 0.01, amp: float = 1.0) -> np.ndarray:
    t = np.arange(0, duration, 1 / RATE)
    return amp * np.sin(2 * np.pi * f * t)


def steps(duration: float, seed: int) -> np.ndarray:
    """Random command levels held 5-20 s."""
    r = np.random.default_rng(seed)
    out = []
    while len(out) < duration * RATE:
        out += [r.uniform(-1, 1)] * int(r.uniform(5, 20) * RATE)
    return np.array(out[: int(duration * RATE)])


def patrol(duration: float, seed: int) -> np.ndarray:
    """Idle holds, creeping, cruise legs, turns, short reversals; every change ramped."""
    r = np.random.default_rng(seed)
    out = [0.0]
    kinds = ["idle", "creep", "cruise", "cruise", "turn", "reverse"]
    while len(out) < duration * RATE:
        k = kinds[r.integers(len(kinds))]
        if k == "idle":
            level, hold = 0.0, r.uniform(20, 120)
        elif k == "creep":
            level, hold = r.choice([-1, 1]) * r.uniform(0.05, 0.2), r.uniform(30, 120)
        elif k == "cruise":
            level, hold = r.uniform(0.35, 0.85), r.uniform(60, 400)
        elif k == "turn":
            level, hold = r.uniform(-0.4, 0.4), r.uniform(10, 30)
        else:
            level, hold = -r.uniform(0.3, 0.7), r.uniform(5, 20)
        ramp = int(r.uniform(2, 6) * RATE)
        out += list(np.linspace(out[-1], level, ramp)) + [level] * int(hold * RATE)
    return np.array(out[: int(duration * RATE)])


def write(
    path: Path, cmd: np.ndarray, rpm: np.ndarray, cur: np.ndarray, v: np.ndarray,
    condition: str, tid: str, labels: bool | None = None,
) -> None:  # fmt: skip
    """A trace CSV; with ``labels`` no condition column (a patrol's truth is in its name)."""
    t = np.arange(len(cmd)) / RATE
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        if labels is None:
            w.writerow(["t", "command", "voltage", "rpm", "current", "condition", "thruster_id"])
            for i in range(len(t)):
                w.writerow(
                    [
                        f"{t[i]:.3f}",
                        f"{cmd[i]:.5f}",
                        f"{v[i]:.4f}",
                        f"{rpm[i]:.2f}",
                        f"{cur[i]:.4f}",
                        condition,
                        tid,
                    ]
                )
        else:
            w.writerow(["t", "command", "voltage", "rpm", "current", "thruster_id"])
            for i in range(len(t)):
                w.writerow(
                    [
                        f"{t[i]:.3f}",
                        f"{cmd[i]:.5f}",
                        f"{v[i]:.4f}",
                        f"{rpm[i]:.2f}",
                        f"{cur[i]:.4f}",
                        tid,
                    ]
                )


VOLT = {
    "nominal_15v": 15.0,
    "nominal_13v": 13.0,
    "nominal_11v8": 11.8,
    "broken_blade_1": 15.0,
    "broken_blade_2": 15.0,
    "biofouling": 15.0,
}


FAULT_SUPPLY_V = 15.3
"""Supply of a faulty patrol, V: the faults of this world's training are at 15 V (+ 0.3)."""


def patrol_unit(
    seed: int, seconds: float, *, drift: bool, fault: str | None = None, fault_at: float = 120.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Command, rpm, current (A) and bus voltage (V) of unit ``seed`` on its own patrol.

    The supply drifts from 16 to 12.5 V with ``drift``, else stays at ``FAULT_SUPPLY_V``; with
    ``fault`` the unit turns ``fault`` at ``fault_at`` s.
    """
    cmd = patrol(seconds, 900 + seed)
    supply = np.linspace(16.0, 12.5, len(cmd)) if drift else np.full(len(cmd), FAULT_SUPPLY_V)
    at = fault_at if fault else None
    return (cmd, *simulate(cmd, supply, "nominal_15v", seed, 77 + seed, at, fault))


def write_training(out: Path, units: range, paper: bool) -> None:
    """Labelled trace CSVs of ``units`` for every class: the paper's 0.01 Hz sine of 200 s, or
    a sine, steps and a patrol (``paper`` False); the supply 0.3 V above each class's."""
    for s in units:
        profiles = (
            {"sine": sine(200)}
            if paper
            else {"sine": sine(300), "steps": steps(300, s), "patrol": patrol(900, 500 + s)}
        )
        for name, cmd in profiles.items():
            for cond, v0 in VOLT.items():
                supply = np.full(len(cmd), v0 + 0.3)
                rpm, cur, v = simulate(
                    cmd, supply, cond, s, zlib.crc32(f"{s}/{name}/{cond}".encode())
                )
                write(out / f"{cond}_{name}_u{s}.csv", cmd, rpm, cur, v, cond, f"u{s}")


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("what", choices=["paper", "rich", "healthy", "faulty"])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--seconds", type=float, default=3600)
    a = p.parse_args()
    if not DATA.is_dir():
        print(f"t200_world: the T200 workbook sheets are not at {DATA}", file=sys.stderr)
        sys.exit(2)
    a.out.mkdir(parents=True, exist_ok=True)
    if a.what in ("paper", "rich"):
        count = 3 if a.what == "paper" else 6
        write_training(a.out, range(a.first_seed, a.first_seed + count), a.what == "paper")
        return
    for k in range(a.runs):
        s = a.first_seed + k
        if a.what == "healthy":
            cmd, rpm, cur, v = patrol_unit(s, a.seconds, drift=True)
            write(a.out / f"healthy_u{s}.csv", cmd, rpm, cur, v, "nominal_15v", f"u{s}", True)
        else:
            fault = list(FAULTS)[k % len(FAULTS)]
            cmd, rpm, cur, v = patrol_unit(s, a.seconds, drift=False, fault=fault)
            write(a.out / f"faulty_{fault}_u{s}.csv", cmd, rpm, cur, v, "", f"u{s}", True)


if __name__ == "__main__":
    main()
