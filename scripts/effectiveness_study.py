"""The effectiveness estimate against the simulator's true thrust (docs/diagnosis.md).

For every case (healthy at the three class voltages; the severity sweep of
``core.sim.plant.SEVERITY_SWEEP``: half a blade to two, light to very heavy fouling) and every
unit seed, simulates the faulty unit and its healthy twin (same seed: the same unit, noise and
commands, same supply) on a command profile, streams the faulty telemetry at 10 Hz through
``core.diagnosis.effectiveness.EffectivenessEstimator`` and compares, every second after
``--settle`` s, the estimate with the truth: the least-squares gain of the faulty thrust against
the healthy twin's over the estimator's window (``Trace.extra["thrust"]``, noise-free).

The estimator chooses the fault family itself (the health node does not use the label).
Off-family variants (``--variants``) scale the thrust loss of a sweep fault by 0.75 and 1.25 at
the same load: faults the estimator's model does not describe exactly. Structural variants
(``--structural``) simulate units built unlike the reference (no dead time or ESC lag, a slew
limit and twice the deadband, a 5x supply sag, an 8 A current limit, twice the friction) while
the reference stays the preset. ``--onset S`` starts the fault at S s (healthy before) and adds
the time to settle within 0.1. A real T200 check (``--t200 DIR``) runs the healthy bench sheets
(scripts/t200_to_trace.py) through the estimator with the t200 reference (truth 1.0).

Usage (after ``. scripts/bootstrap.sh``)::

    python scripts/effectiveness_study.py --seeds 20 --first-seed 500 --out out/eff
        [--signals mission multilevel] [--duration 300] [--preset t100] [--variants]
        [--structural] [--onset 120 --settle 0] [--t200 ../shared/data/t200]
        [--plot docs/img/effectiveness.png] [--replot RUNS_JSON]

Writes ``OUT/runs.json`` (every run's errors) and ``OUT/table.md`` (the Markdown table it prints).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from thruster_fdd.core.atomic import replaced_file, write_text
from thruster_fdd.core.diagnosis.effectiveness import EffectivenessEstimator
from thruster_fdd.core.diagnosis.reference import ThrustReference
from thruster_fdd.core.traces.data import Trace
from thruster_fdd_shore.core.reference import reference_of
from thruster_fdd_shore.core.sim.config import SimConfig, load_config
from thruster_fdd_shore.core.sim.effects import make_effect
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator, simulate
from thruster_fdd_shore.core.sim.plant import SEVERITY_SWEEP, ConditionSpec, severity_spec
from thruster_fdd_shore.core.sim.signals import make_signal

RATE_HZ = 10.0
"""Sample rate of the streamed telemetry (the nominal model's, what the health node sees), Hz."""

HEALTHY = {"nominal_15v": 15.0, "nominal_13v": 13.0, "nominal_11v8": 11.8}
"""Healthy cases: class name -> supply voltage, V."""

MIN_DEMAND = 0.05
"""A window is scored when the healthy twin's RMS thrust over it reaches this share of its
largest thrust in the run: the effectiveness, a ratio of thrusts, means little when next to no
thrust is asked for."""

CLASS_OF = {"blades": ("broken_blade_1", "broken_blade_2"), "fouling": ("biofouling",)}


@dataclass(frozen=True)
class Case:
    """One simulated condition.

    Attributes
    ----------
    name : str
        Case name (a ``SEVERITY_SWEEP`` name, a healthy class, or a variant).
    family : str
        ``"blades"``, ``"fouling"`` or ``""`` (healthy).
    severity : float
        Severity of the family (0 healthy).
    label : str
        The class the simulator names the condition with (the nearest class).
    spec : ConditionSpec
        The physics simulated.
    """

    name: str
    family: str
    severity: float
    label: str
    spec: ConditionSpec


def cases(variants: bool) -> list[Case]:
    """Healthy cases, the severity sweep and, with ``variants``, off-family faults."""
    out = [Case(c, "", 0.0, c, ConditionSpec(v)) for c, v in HEALTHY.items()]
    for name, (family, severity) in SEVERITY_SWEEP.items():
        label = CLASS_OF[family][0 if family == "fouling" or severity < 1.5 else 1]
        out.append(Case(name, family, severity, label, severity_spec(family, severity)))
    if variants:
        for name, (family, severity) in SEVERITY_SWEEP.items():
            if severity not in (0.5, 1.0, 1.5):
                continue
            label = CLASS_OF[family][0 if family == "fouling" or severity < 1.5 else 1]
            base = severity_spec(family, severity)
            for factor in VARIANT_LOSS_FACTORS:
                loss = (1.0 - base.k_thrust_factor) * factor
                spec = replace(base, k_thrust_factor=1.0 - loss)
                out.append(Case(f"{name}, thrust loss x{factor:g}", family, severity, label, spec))
    return out


VARIANT_LOSS_FACTORS = (0.75, 1.25)
"""Off-family variants: the thrust loss ``1 - k_thrust_factor`` of a sweep fault scaled by these,
its load unchanged (a fault whose thrust the severity ladder does not describe exactly)."""


def structural_variants(preset: str) -> dict[str, SimConfig]:
    """Units built unlike the reference: effects of the command path and the supply changed.

    The reference curves stay the preset's; these show what the estimate assumes about the
    unit's structure.
    """
    base = load_config(preset)

    def with_effects(**changes: dict[str, float] | None) -> SimConfig:
        effects = {e.name: e.params() for e in base.effects}
        for name, values in changes.items():
            if values is None:
                effects.pop(name, None)
            else:
                effects[name] = values
        return replace(base, effects=tuple(make_effect(n, v) for n, v in effects.items()))

    return {
        "no dead time, no ESC lag": with_effects(dead_time=None, esc_lag=None),
        "slew limit 1/s, deadband x2": with_effects(
            slew_rate_limit={"rate_per_s": 1.0},
            deadband={
                "width": 2
                * (base.effect("deadband").params()["width"] if base.effect("deadband") else 0.03)
            },
        ),
        "supply sag 0.15 ohm": with_effects(voltage_sag={"r_internal_ohm": 0.15}),
        "current limit 8 A": with_effects(current_limit={"i_max_a": 8.0}),
        "friction x2": with_effects(
            coulomb_friction={"torque_nm": 2 * _param(base, "coulomb_friction", "torque_nm")},
            viscous_friction={"coeff": 2 * _param(base, "viscous_friction", "coeff")},
        ),
    }


def _param(config: SimConfig, effect: str, name: str) -> float:
    e = config.effect(effect)
    return float(e.params()[name]) if e is not None else 0.0


def run_case(
    config: SimConfig,
    reference: ThrustReference,
    case: Case,
    seed: int,
    *,
    signal: str = "mission",
    duration_s: float = 300.0,
    settle_s: float = 60.0,
    onset_s: float = 0.0,
) -> dict[str, np.ndarray]:
    """One unit on one profile: truth and estimate every second from ``onset_s + settle_s``.

    The unit is healthy before ``onset_s`` (s) and in ``case`` from then on; its healthy twin
    (same seed, same supply) gives the truth.

    Returns
    -------
    dict
        ``t`` (s), ``truth``, ``value``, ``std``, ``severity`` (arrays of shape (n,)).
    """
    t, command = make_signal(signal, duration_s, RATE_HZ, seed=seed)
    voltage = case.spec.supply_v
    healthy = simulate(config, t, command, "nominal_15v", voltage=voltage, seed=seed)
    if onset_s <= 0.0:
        faulty = simulate(
            config, t, command, case.label, voltage=voltage, seed=seed, spec=case.spec
        )
    else:
        sim = ThrusterSimulator(config, "nominal_15v", voltage=voltage, seed=seed)
        rows, previous = [], t[0]
        for ti, ci in zip(t.tolist(), command.tolist(), strict=True):
            if ti >= onset_s and sim.condition != case.label:
                sim.set_condition(case.label, case.spec)
            s = sim.step(ci, ti - previous)
            previous = ti
            rows.append((s.command, s.voltage, s.rpm, s.current, s.thrust))
        out = np.array(rows)
        faulty = Trace(t, out[:, 0], out[:, 1], out[:, 2], out[:, 3], extra={"thrust": out[:, 4]})
    return stream(EffectivenessEstimator(reference), faulty, healthy, onset_s + settle_s)


def stream(
    estimator: EffectivenessEstimator,
    faulty: Trace,
    healthy: Trace | None,
    from_s: float,
) -> dict[str, np.ndarray]:
    """Stream ``faulty`` through ``estimator``; every second from ``from_s`` (s after the first
    sample) the estimate and the truth (thrust gain against ``healthy``; 1.0 when None)."""
    n_window = round(estimator.window_s * RATE_HZ)
    thrust_scale = 0.0 if healthy is None else float(np.max(np.abs(healthy.extra["thrust"])))
    out: dict[str, list[float]] = {k: [] for k in ("t", "truth", "value", "std", "severity")}
    hop = round(RATE_HZ)
    for i in range(len(faulty)):
        estimator.push(
            float(faulty.t[i]),
            float(faulty.command[i]),
            float(faulty.voltage[i]),
            float(faulty.rpm[i]),
            float(faulty.current[i]),
        )
        if faulty.t[i] - faulty.t[0] < from_s or i % hop:
            continue
        if healthy is None:
            truth = 1.0
        else:
            window = slice(max(0, i + 1 - n_window), i + 1)
            t_f, t_h = faulty.extra["thrust"][window], healthy.extra["thrust"][window]
            den = float(t_h @ t_h)
            if den < (MIN_DEMAND * thrust_scale) ** 2 * len(t_h):  # next to no thrust asked for
                continue
            truth = float(t_f @ t_h) / den
        e = estimator.estimate()
        out["t"].append(float(faulty.t[i]))
        out["truth"].append(truth)
        out["value"].append(e.value)
        out["std"].append(e.std)
        out["severity"].append(e.severity)
    return {k: np.asarray(v) for k, v in out.items()}


def settling_time(run: dict[str, np.ndarray], onset_s: float, tolerance: float = 0.1) -> float:
    """Time from ``onset_s`` until the error stays within ``tolerance``, s (inf if it never
    does before the run ends)."""
    bad = np.abs(run["value"] - run["truth"]) > tolerance
    if not bad.any():
        return 0.0
    last = int(np.flatnonzero(bad)[-1])
    return math.inf if last == len(bad) - 1 else float(run["t"][last + 1] - onset_s)


def summary(runs: list[dict[str, np.ndarray]], onset_s: float | None = None) -> dict[str, float]:
    """Median and 95th percentile of the absolute error, bias, coverage of +-1 std; with
    ``onset_s``, also the median and largest time to settle within 0.05 after the onset."""
    truth = np.concatenate([r["truth"] for r in runs])
    err = np.concatenate([r["value"] - r["truth"] for r in runs])
    std = np.concatenate([r["std"] for r in runs])
    if err.size == 0:
        return {"n": 0}
    return {
        "n": int(err.size),
        "truth_median": float(np.median(truth)),
        "truth_min": float(truth.min()),
        "truth_max": float(truth.max()),
        "median_abs": float(np.median(np.abs(err))),
        "p95_abs": float(np.percentile(np.abs(err), 95)),
        "bias": float(np.median(err)),
        "coverage_1sd": float(np.mean(np.abs(err) <= std)),
        "std_median": float(np.median(std)),
    } | ({} if onset_s is None else _settling(runs, onset_s))


def _settling(runs: list[dict[str, np.ndarray]], onset_s: float) -> dict[str, float]:
    times = [settling_time(r, onset_s) for r in runs]
    return {"settle_median_s": float(np.median(times)), "settle_max_s": float(np.max(times))}


def t200_check(data_dir: Path) -> dict[str, float]:
    """Healthy real T200 bench sheets through the estimator with the t200 reference."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from t200_to_trace import steps_trace

    trace = steps_trace(data_dir)
    dt = np.diff(trace.t, prepend=trace.t[0] - 1.0 / RATE_HZ)
    # The sheets are steady-state rows held for a while each: stream them at 10 Hz.
    t = np.cumsum(np.maximum(dt, 1.0 / RATE_HZ))
    trace = replace(trace, t=t)
    estimator = EffectivenessEstimator(reference_of(load_config("t200")))
    return summary([stream(estimator, trace, None, 120.0)])


def _table(rows: list[tuple[str, dict[str, float]]]) -> str:
    settle = any("settle_median_s" in s for _, s in rows)
    lines = [
        "| case | windows | true effectiveness median (range) | abs. error median | p95 | bias "
        "| within 1 std |" + (" settled within 0.1, median / max s |" if settle else ""),
        "|---|---|---|---|---|---|---|" + ("---|" if settle else ""),
    ]
    for name, s in rows:
        if not s.get("n"):
            lines.append(f"| {name} | 0 | - | - | - | - | - |")
            continue
        lines.append(
            f"| {name} | {s['n']} | {s['truth_median']:.3f} ({s['truth_min']:.2f}-"
            f"{s['truth_max']:.2f}) | {s['median_abs']:.3f} | {s['p95_abs']:.3f} | "
            f"{s['bias']:+.3f} | {s['coverage_1sd']:.2f} |"
            + (
                f" {s['settle_median_s']:.0f} / {s['settle_max_s']:.0f} |"
                if "settle_median_s" in s
                else ""
            )
        )
    return "\n".join(lines)


def _plot(path: Path, per_case: dict[str, list[dict[str, np.ndarray]]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    names = [n for n in per_case if n in SEVERITY_SWEEP or n in HEALTHY]
    colors = plt.cm.tab20(np.linspace(0.0, 1.0, 20))
    for i, name in enumerate(names):
        runs = per_case[name]
        truth = np.concatenate([r["truth"] for r in runs])
        value = np.concatenate([r["value"] for r in runs])
        if truth.size:
            axes[0].scatter(truth, value, s=2, alpha=0.3, label=name, color=colors[i % 20])
    axes[0].plot([0.3, 1.05], [0.3, 1.05], "k--", lw=0.8)
    axes[0].set_xlabel("true effectiveness (simulated thrust / healthy twin's)")
    axes[0].set_ylabel("estimated effectiveness")
    axes[0].legend(fontsize=7, markerscale=4, loc="upper left")
    data = [np.abs(np.concatenate([r["value"] - r["truth"] for r in per_case[n]])) for n in names]
    axes[1].boxplot(data, whis=(5, 95), showfliers=False)
    axes[1].set_xticks(range(1, len(names) + 1), names, rotation=60, ha="right", fontsize=8)
    axes[1].axhline(0.05, color="g", lw=0.8, ls="--")
    axes[1].axhline(0.10, color="r", lw=0.8, ls="--")
    axes[1].set_ylabel("|error| (box: quartiles, whiskers: 5-95 %)")
    fig.tight_layout()
    with replaced_file(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="t100")
    p.add_argument("--seeds", type=int, default=6)
    p.add_argument("--first-seed", type=int, default=10)
    p.add_argument("--signals", nargs="+", default=["mission"])
    p.add_argument("--duration", type=float, default=300.0)
    p.add_argument("--settle", type=float, default=60.0)
    p.add_argument("--onset", type=float, default=0.0, help="fault onset, s (healthy before)")
    p.add_argument("--variants", action="store_true", help="also off-family faults")
    p.add_argument("--structural", action="store_true", help="also units built unlike the preset")
    p.add_argument("--t200", type=Path, metavar="DIR")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--plot", type=Path)
    p.add_argument("--replot", type=Path, metavar="RUNS_JSON", help="only plot a former run")
    args = p.parse_args(argv)
    if args.replot is not None:
        runs = json.loads(args.replot.read_text())["runs"]
        _plot(
            args.plot,
            {n: [{k: np.asarray(v) for k, v in r.items()} for r in rs] for n, rs in runs.items()},
        )
        return 0
    config = load_config(args.preset)
    reference = reference_of(config)
    units = {"": config}
    if args.structural:
        units |= {f" ({name})": c for name, c in structural_variants(args.preset).items()}
    per_case: dict[str, list[dict[str, np.ndarray]]] = {}
    for suffix, unit in units.items():
        for case in cases(args.variants and not suffix):
            name = case.name + suffix
            for signal in args.signals:
                for seed in range(args.first_seed, args.first_seed + args.seeds):
                    run = run_case(
                        unit,
                        reference,
                        case,
                        seed,
                        signal=signal,
                        duration_s=args.duration,
                        settle_s=args.settle,
                        onset_s=args.onset,
                    )
                    per_case.setdefault(name, []).append(run)
            print(f"{name}: {summary(per_case[name])}", file=sys.stderr, flush=True)
    onset = args.onset if args.onset > 0 else None
    rows = [(name, summary(runs, onset)) for name, runs in per_case.items()]
    faults = [r for n, runs in per_case.items() for r in runs if n in SEVERITY_SWEEP]
    rows.append(("all sweep faults", summary(faults, onset)))
    family = [
        r for n, runs in per_case.items() for r in runs if n in SEVERITY_SWEEP or n in HEALTHY
    ]
    rows.append(("healthy and sweep faults", summary(family, onset)))
    if args.t200 is not None:
        rows.append(("real T200 sheets, healthy (t200 reference)", t200_check(args.t200)))
    table = _table(rows)
    print(table)
    document = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "summary": dict(rows),
        "runs": {
            n: [{k: v.tolist() for k, v in r.items()} for r in runs] for n, runs in per_case.items()
        },
    }
    write_text(args.out / "runs.json", json.dumps(document) + "\n")
    write_text(args.out / "table.md", table + "\n")
    if args.plot is not None:
        _plot(args.plot, per_case)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
