"""Plot the simulator's reference figures into docs/img/.

- ``step_response.png``: t100 response to the paper's 0.25 command steps (noisy telemetry).
- ``sine_hysteresis.png``: t100 command-rpm loops for 0.01-0.04 Hz sines.
- ``t200_fit.png``: t200 preset against the real T200 measurements at 10-20 V.

Usage: ``python scripts/plot_simulator.py [--data ../shared/data/t200] [--out docs/img]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from thruster_fdd_shore.core.sim.config import Measurement, load_config
from thruster_fdd_shore.core.sim.metrics import hysteresis_loop_area
from thruster_fdd_shore.core.sim.physics import simulate
from thruster_fdd_shore.core.sim.signals import make_signal
from thruster_fdd_shore.core.sim.steady import steady_state

REPO = Path(__file__).resolve().parents[1]


def plot_steps(out: Path) -> None:
    config = load_config("t100")
    t, u = make_signal("steps", 160.0, 10.0)
    trace = simulate(config, t, u, seed=1)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    ax1.plot(trace.t, trace.rpm, lw=0.8, label="rpm (measured)")
    ax1b = ax1.twinx()
    ax1b.step(trace.t, trace.command, where="pre", color="k", lw=0.8, label="command")
    ax1.set_ylabel("rpm")
    ax1b.set_ylabel("command")
    ax2.plot(trace.t, trace.current, lw=0.8, color="C1")
    ax2.set_ylabel("bus current (A)")
    ax2.set_xlabel("t (s)")
    ax1.set_title("t100, nominal_15v: paper's 0.25 command steps")
    fig.tight_layout()
    fig.savefig(out / "step_response.png", dpi=110)
    plt.close(fig)


def plot_hysteresis(out: Path) -> None:
    config = dataclasses.replace(load_config("t100"), measurement=Measurement(), spread=0.0)
    fig, ax = plt.subplots(figsize=(6, 5))
    for freq in (0.01, 0.02, 0.03, 0.04):
        t, u = make_signal(f"sine:{freq}", 2.0 / freq, 20.0)
        trace = simulate(config, t, u)
        half = len(t) // 2
        area = hysteresis_loop_area(trace.command[half:], trace.rpm[half:], 4000.0)
        ax.plot(trace.command[half:], trace.rpm[half:], lw=1, label=f"{freq} Hz, area {area:.2f}")
    ax.set_xlabel("command")
    ax.set_ylabel("rpm")
    ax.set_title("t100 command-rpm loops (area with rpm / 4000)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "sine_hysteresis.png", dpi=110)
    plt.close(fig)


def plot_t200(out: Path, data: Path) -> None:
    spec = importlib.util.spec_from_file_location(
        "calibrate_t200", REPO / "scripts" / "calibrate_t200.py"
    )
    cal = importlib.util.module_from_spec(spec)
    sys.modules["calibrate_t200"] = cal  # dataclasses look their module up while building
    spec.loader.exec_module(cal)
    config = load_config("t200")
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    for k, sheet in enumerate(cal.load_sheets(data)):
        rpm, cur = steady_state(
            config, (sheet.pwm_us - 1500.0) / 400.0, sheet.voltage, reported=True
        )
        color = f"C{k}"
        ax1.plot(sheet.pwm_us, sheet.rpm, ".", ms=3, color=color, label=f"{sheet.voltage:g} V data")
        ax1.plot(sheet.pwm_us, np.abs(rpm), "-", lw=1, color=color)
        ax2.plot(sheet.pwm_us, sheet.current, ".", ms=3, color=color)
        ax2.plot(sheet.pwm_us, cur, "-", lw=1, color=color)
    ax1.set_ylabel("|rpm|")
    ax2.set_ylabel("current (A)")
    for ax in (ax1, ax2):
        ax.set_xlabel("PWM (us)")
    ax1.legend(fontsize=7)
    fig.suptitle("t200 preset (lines) vs Blue Robotics T200 measurements (dots)")
    fig.tight_layout()
    fig.savefig(out / "t200_fit.png", dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "t200")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "img")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    plot_steps(args.out)
    plot_hysteresis(args.out)
    plot_t200(args.out, args.data)
    print(f"wrote step_response.png, sine_hysteresis.png, t200_fit.png to {args.out}")


if __name__ == "__main__":
    main()
