"""Where the simulator disagrees with a measurement, and the discrepancy report files.

``regions`` splits the squared residual of rpm and current over operating regions, ``signatures``
measures the cues that point to causes, ``write_report`` writes report.json, model.yaml,
report.md, details.json and the PNG plots of ``thruster-fdd discrepancy``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from thruster_fdd.core.discrepancy.fit import Fit
from thruster_fdd.core.discrepancy.measure import (
    Measured,
    describe,
    regions,
    reported,
    signatures,
    simulate_model,
    weighted_residuals,
)
from thruster_fdd.core.discrepancy.search import MIN_GAIN, STRUCTURED, Result
from thruster_fdd.core.sim.config import dump_config


def _plots(result: Result, data: Measured, sims: dict[str, dict], out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = []
    held_idx = np.flatnonzero(data.held)
    breaks = np.flatnonzero(np.diff(held_idx) > 1) + 1
    blocks = np.split(held_idx, breaks)
    block = blocks[len(blocks) // 2]
    seg = block[(data.t[block] - data.t[block[0]]) <= 90.0]
    colors = {"measured": "k", "before": "tab:red", "after": "tab:blue"}

    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for ax, ch, unit in ((axes[0], "rpm", "rpm"), (axes[1], "current", "A")):
        ax.plot(
            data.t[seg], data.channel(ch)[seg], color=colors["measured"], lw=1.0, label="measured"
        )
        for key in ("before", "after"):
            ax.plot(
                data.t[seg],
                reported(sims[key], data)[ch][seg],
                color=colors[key],
                lw=1.0,
                label=f"model {key}",
            )
        ax.set_ylabel(f"{ch} ({unit})")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[1].set_xlabel("t (s), held-out data")
    fig.suptitle("Overlay before / after the added effects (held-out)")
    fig.tight_layout()
    fig.savefig(out / "overlay.png", dpi=110)
    plt.close(fig)
    names.append("overlay.png")

    fig, axes = plt.subplots(2, 2, figsize=(10, 6), sharex=True)
    for col, key in enumerate(("before", "after")):
        res = weighted_residuals(sims[key], data)
        for row, (ch, unit) in enumerate((("rpm", "rpm"), ("current", "A"))):
            ax = axes[row, col]
            ax.scatter(
                data.command[data.held], res[ch][data.held], s=2, alpha=0.4, color=colors[key]
            )
            ax.axhline(0.0, color="k", lw=0.5)
            ax.set_ylabel(f"{ch} residual ({unit})")
            ax.set_title(f"model {key}", fontsize=9)
            ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("command")
    fig.suptitle("Residual (measured - model) against command, held-out")
    fig.tight_layout()
    fig.savefig(out / "residual_vs_command.png", dpi=110)
    plt.close(fig)
    names.append("residual_vs_command.png")

    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot(data.command[seg], data.rpm[seg], color="k", lw=1.0, label="measured")
    for key in ("before", "after"):
        ax.plot(
            data.command[seg],
            reported(sims[key], data)["rpm"][seg],
            color=colors[key],
            lw=1.0,
            label=f"model {key}",
        )
    ax.set_xlabel("command")
    ax.set_ylabel("rpm")
    ax.set_title("Command-rpm loop (hysteresis), held-out")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "hysteresis.png", dpi=110)
    plt.close(fig)
    names.append("hysteresis.png")
    return names


def _fmt(x: float) -> str:
    if not math.isfinite(x):
        return str(x)
    return f"{x:.4g}"


def _gap_rows(label: str, fit: Fit) -> str:
    g = fit.gap
    return (
        f"| {label} | {g.rpm_rmse:.1f} | {g.rpm_r2:.4f} | {g.current_rmse:.3f} | "
        f"{g.current_r2:.4f} | {g.voltage_rmse:.3f} | {g.score:.2f} |"
    )


def markdown(result: Result, data: Measured, sims: dict[str, dict], plots: list[str]) -> str:
    """The report.md text."""
    rep = result.report()
    lines = [
        "# Discrepancy report",
        "",
        f"**Verdict: `{rep['verdict']}`**"
        + (f" — missing: {', '.join(f'`{n}`' for n in result.added)}" if result.added else ""),
        "",
    ]
    if result.added and result.final.gap.score > STRUCTURED:
        why = (
            "no further candidate of the vocabulary explains it"
            if result.rounds[-1].chosen is None
            else f"the search stopped after {len(result.rounds)} rounds"
        )
        lines += [
            f"The residual after them is still structured (held-out score "
            f"{result.final.gap.score:.1f} > {STRUCTURED:g}) and {why}: see where the model "
            f"after disagrees, below.",
            "",
        ]
    lines += [
        f"Samples: {len(data.t)} over {data.t[-1]:.0f} s; fit on {int(data.fit.sum())}, "
        f"held out {int(data.held.sum())} (interleaved blocks). Noise estimate: "
        f"rpm {data.sigma['rpm']:.3g}, current {data.sigma['current']:.3g} A, "
        f"voltage {data.sigma['voltage']:.3g} V.",
        "",
    ]
    lines += [f"- warning: {w}" for w in result.warnings]
    lines += ["", "## Named missing effects", ""]
    if rep["missing_effects"]:
        lines += ["| effect | parameter | value | std |", "|---|---|---|---|"]
        for m in rep["missing_effects"]:
            for p, v in m["params"].items():
                lines.append(f"| `{m['name']}` | {p} | {_fmt(v)} | {_fmt(m['uncertainty'][p])} |")
    else:
        lines.append("none")
    lines += [
        "",
        "## Gap on held-out data, after each step",
        "",
        "score: mean squared residual per channel in noise-variance units (1 = noise only).",
        "",
        "| model | rpm RMSE | rpm r² | current RMSE (A) | current r² | voltage RMSE (V) | score |",
        "|---|---|---|---|---|---|---|",
        _gap_rows("calibrated start", result.start),
    ]
    for rnd in result.rounds:
        chosen = next((c for c in rnd.candidates if c.name == rnd.chosen), None)
        if chosen is not None:
            lines.append(_gap_rows(f"+ {chosen.name} (candidate re-fit)", chosen.fit))
    lines += [_gap_rows("final (calibrated)", result.final), ""]
    for k, rnd in enumerate(result.rounds, 1):
        lines += [
            f"## Round {k}: candidates",
            "",
            f"Accepted: ΔBIC < 0 on the fit samples, and a held-out gain and an own gain of at "
            f"least {MIN_GAIN:g} (gain: the fraction of the excess over noise removed; own gain: "
            f"what taking the effect out of the re-fit again costs on the fit samples).",
            "",
            "| effect | ΔBIC (fit) | held-out gain | own gain | held-out score | accepted |",
            "|---|---|---|---|---|---|",
        ]
        for c in sorted(rnd.candidates, key=lambda c: c.fit.gap.score):
            lines.append(
                f"| `{c.name}` | {c.delta_bic:.1f} | {c.gain:.2f} | {c.own_gain:.2f} | "
                f"{c.fit.gap.score:.2f} | {'yes' if c.accepted else 'no'} |"
            )
        lines.append("")
    for key in ("before", "after"):
        sim = sims[key]
        lines += [f"## Where the model {key} disagrees (held-out)", ""]
        lines += [f"- {s}" for s in describe(signatures(sim, data))]
        lines += [
            "",
            "| signal | region | share of squared error | share of samples | RMSE |",
            "|---|---|---|---|---|",
        ]
        for r in regions(sim, data, data.held):
            lines.append(
                f"| {r.signal} | {r.region} | {r.error_share:.2f} | "
                f"{r.sample_share:.2f} | {r.rmse:.3g} |"
            )
        lines.append("")
    lines += ["## Plots", ""] + [f"![{p}]({p})" for p in plots] + [""]
    return "\n".join(lines)


def write_report(result: Result, data: Measured, out: str | Path) -> dict[str, Path]:
    """Write report.json, model.yaml, report.md, details.json and PNG plots into ``out``.

    Returns
    -------
    dict of str to Path
        File kind -> written path.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sims = {
        "before": simulate_model(result.start.config, data),
        "after": simulate_model(result.final.config, data),
    }
    plots = _plots(result, data, sims, out)
    (out / "report.json").write_text(json.dumps(result.report(), indent=2) + "\n")
    dump_config(result.final.config, out / "model.yaml")
    (out / "report.md").write_text(markdown(result, data, sims, plots))
    details = {
        "warnings": list(result.warnings),
        "signatures_before": signatures(sims["before"], data),
        "signatures_after": signatures(sims["after"], data),
        "regions_before": [r.__dict__ for r in regions(sims["before"], data, data.held)],
        "regions_after": [r.__dict__ for r in regions(sims["after"], data, data.held)],
        "rounds": [
            {
                "chosen": rnd.chosen,
                "candidates": [
                    {
                        "name": c.name,
                        "delta_bic": c.delta_bic,
                        "gain": c.gain,
                        "held_out_score": c.fit.gap.score,
                        "own_gain": c.own_gain,
                        "accepted": c.accepted,
                    }
                    for c in rnd.candidates
                ],
            }
            for rnd in result.rounds
        ],
        "gap_score_before": result.start.gap.score,
        "gap_score_after": result.final.gap.score,
        "fitted": dict(zip(result.final.names, result.final.values.tolist(), strict=True)),
    }
    (out / "details.json").write_text(json.dumps(details, indent=2) + "\n")
    files = {
        "report.json": out / "report.json",
        "model.yaml": out / "model.yaml",
        "report.md": out / "report.md",
        "details.json": out / "details.json",
    }
    files.update({p: out / p for p in plots})
    return files
