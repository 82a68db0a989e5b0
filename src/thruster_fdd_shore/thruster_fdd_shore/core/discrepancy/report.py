"""The discrepancy report files of ``thruster-fdd discrepancy``.

``write_report`` writes report.json, model.yaml, report.md, details.json and the PNG plots into
a staging folder that replaces the output folder only once everything is written
(``core.atomic.replaced_dir``); ``check_out_dir`` refuses an output folder that holds anything
else, before the workflow runs.
"""

from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path

import numpy as np

from thruster_fdd.core.atomic import replaced_dir, write_text
from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.core.discrepancy import moves
from thruster_fdd_shore.core.discrepancy.correction import KINDS
from thruster_fdd_shore.core.discrepancy.engine import Result, policy_dict, structured
from thruster_fdd_shore.core.discrepancy.fit import BASE_RANGE
from thruster_fdd_shore.core.discrepancy.measure import (
    Measured,
    reported,
    simulate_model,
    weighted_residuals,
)
from thruster_fdd_shore.core.discrepancy.score import excess
from thruster_fdd_shore.core.discrepancy.where import describe, gap, regions, signatures
from thruster_fdd_shore.core.json_text import json_text
from thruster_fdd_shore.core.sim.config import SimConfig, dump_config

REPORT_FILES = (
    "report.json",
    "model.yaml",
    "report.md",
    "details.json",
    "overlay.png",
    "residual_vs_command.png",
    "hysteresis.png",
)
"""Every file ``write_report`` writes."""


def check_out_dir(out: str | Path) -> None:
    """BadInputError unless ``out`` is new, empty, or holds only an earlier report's files.

    The report replaces the whole folder, so a folder holding anything else is refused.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise BadInputError(f"--out {out}: exists and is not a folder")
    if out.is_dir():
        other = sorted(p.name for p in out.iterdir() if p.name not in REPORT_FILES)
        if other:
            raise BadInputError(
                f"--out {out}: holds files other than a discrepancy report ({', '.join(other[:3])}"
                f"{', ...' if len(other) > 3 else ''}); the report replaces the whole folder, "
                "give a new or empty one"
            )


def _plots(data: Measured, sims: dict[str, dict], out: Path) -> list[str]:
    """overlay.png, residual_vs_command.png and hysteresis.png of the start (``before``) and
    final (``after``) models on held-out data (up to 90 s of the middle held-out block)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    held = np.flatnonzero(data.held)
    blocks = np.split(held, np.flatnonzero(np.diff(held) > 1) + 1)
    seg = blocks[len(blocks) // 2]
    seg = seg[data.t[seg] - data.t[seg[0]] <= 90.0]
    colors = {"before": "tab:red", "after": "tab:blue"}
    rep = {k: reported(sim, data) for k, sim in sims.items()}
    units = (("rpm", "rpm"), ("current", "A"))

    def save(fig, name: str, title: str) -> str:
        fig.suptitle(title)
        fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        return name

    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for ax, (ch, unit) in zip(axes, units, strict=True):
        ax.plot(data.t[seg], data.channel(ch)[seg], color="k", lw=1.0, label="measured")
        for key, color in colors.items():
            ax.plot(data.t[seg], rep[key][ch][seg], color=color, lw=1.0, label=f"model {key}")
        ax.set_ylabel(f"{ch} ({unit})")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[1].set_xlabel("t (s), held-out data")
    names = [save(fig, "overlay.png", "Overlay before / after the added effects (held-out)")]

    fig, axes = plt.subplots(2, 2, figsize=(10, 6), sharex=True)
    for col, (key, color) in enumerate(colors.items()):
        res = weighted_residuals(sims[key], data)
        for row, (ch, unit) in enumerate(units):
            ax = axes[row, col]
            ax.scatter(data.command[data.held], res[ch][data.held], s=2, alpha=0.4, color=color)
            ax.axhline(0.0, color="k", lw=0.5)
            ax.set(ylabel=f"{ch} residual ({unit})", xlabel="command" if row else "")
            ax.set_title(f"model {key}", fontsize=9)
            ax.grid(alpha=0.3)
    title = "Residual (measured - model) against command, held-out"
    names.append(save(fig, "residual_vs_command.png", title))

    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot(data.command[seg], data.rpm[seg], color="k", lw=1.0, label="measured")
    for key, color in colors.items():
        ax.plot(data.command[seg], rep[key]["rpm"][seg], color=color, lw=1.0, label=f"model {key}")
    ax.set(xlabel="command", ylabel="rpm")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    names.append(save(fig, "hysteresis.png", "Command-rpm loop (hysteresis), held-out"))
    return names


FRICTION_UNITS = {"coulomb_friction": ("torque_nm", "A"), "viscous_friction": ("coeff", "A s/rad")}
"""Friction effects restated as motor current: parameter, unit of parameter / k_e."""


def friction_currents(config: SimConfig) -> dict[str, float]:
    """The friction effects of ``config`` as the motor current they draw (parameter / k_e, in
    ``FRICTION_UNITS``): with the drive losses free, k_e and a friction torque trade along a
    valley of equal fit (docs/discrepancy.md), so the current is what the data pin down."""
    return {
        name: getattr(effect, param) / config.params.k_e
        for name, (param, _unit) in FRICTION_UNITS.items()
        if (effect := config.effect(name)) is not None
    }


def _fmt(x: float) -> str:
    return f"{x:.4g}" if math.isfinite(x) else str(x)


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


BASE_VALUES = {
    **moves.UNDONE,
    "second ESC stage": (*moves.UNDONE["second ESC stage"], "esc_lag.tau_s"),
}
"""Values a base change is reported with: the terms it changes (``moves.UNDONE``), the lag the
second stage shortens; for ``widen bounds`` only the parameters it widened."""


def _value(config: SimConfig, key: str) -> float | bool:
    owner, name = key.split(".")
    if owner in ("params", "structure"):
        return getattr(config.params if owner == "params" else config.structure, name)
    effect = config.effect(owner)
    return effect.params()[name] if effect is not None else math.nan


def base_changes(result: Result) -> list[dict]:
    """The base changes the search made, each with the values it brought."""
    spec, config = result.scored.spec, result.final.config
    out = []
    for label in spec.changes:
        keys = BASE_VALUES[label]
        if label == "widen bounds":
            keys = [k for k in spec.ranges if k in keys]
        out.append({"change": label, "values": {k: _value(config, k) for k in keys}})
    return out


def at_bound(result: Result) -> list[str]:
    """Base parameters of the final model within 5 % of their calibration bound, described."""
    config, anchor, ranges = result.final.config, result.anchor, result.scored.spec.ranges
    out = []
    for key in moves.at_bound(config, anchor, ranges):
        value, ref = (_value(c, key) for c in (config, anchor))
        factor = ranges.get(key, BASE_RANGE)
        out.append(f"{key.split('.')[1]} {_fmt(value)} (start {_fmt(ref)}, bound x{factor:g})")
    return out


REST_REGIONS = 2
"""Regions per signal listed in report.json's ``rest.where`` (the largest error shares)."""


def rest(result: Result, data: Measured, sim_after: dict) -> dict:
    """What the final model leaves: whether it is structured (a group of the generic
    correction explains part of it, or its held-out variance ``score`` exceeds the policy's
    ``structured`` noise variances), of which kind (the group of the largest such gain),
    each group's gain and standard error (nats), where it lies (the largest error shares per
    signal) and the residual's cues."""
    found = [g for g, (_gain, _se, sig) in result.rest.items() if sig]
    kind = max(found, key=lambda g: result.rest[g][0]) if found else None
    is_structured = structured(result.scored, data, result.policy, result.rest)
    keys = ("signal", "region", "error_share", "sample_share")
    listed = regions(sim_after, data, data.held)
    where = [
        {k: getattr(r, k) for k in keys}
        for signal in ("rpm", "current")
        for r in [r for r in listed if r.signal == signal][:REST_REGIONS]
    ]
    return {
        "structured": is_structured,
        "score": excess(result.scored, data, result.policy),
        "kind": KINDS[kind] if kind else None,
        "gains": {g: {"gain": v[0], "se": v[1]} for g, v in result.rest.items()},
        "where": where if is_structured else [],
        "cues": describe(signatures(sim_after, data)),
    }


GAP_KEYS = ("rpm_rmse", "current_rmse", "rpm_r2", "current_r2")
"""The keys of report.json's ``gap_before`` / ``gap_after`` (``where.gap``)."""


def simulations(result: Result, data: Measured) -> dict[str, dict]:
    """The start's (``before``) and the final model's (``after``) simulations of ``data``."""
    return {
        "before": simulate_model(result.start.config, data),
        "after": simulate_model(result.final.config, data),
    }


def gaps_of(sims: dict[str, dict], data: Measured) -> dict[str, dict[str, float]]:
    """``where.gap`` of the start's (``before``) and the final model's (``after``) simulations."""
    return {key: gap(sim, data) for key, sim in sims.items()}


def report_json(result: Result, data: Measured, sims: dict[str, dict], gaps: dict) -> dict:
    """The report.json mapping (docs/contracts.md); ``sims``: the start's (``before``) and the
    final model's (``after``) simulations; ``gaps``: theirs (``gaps_of``)."""
    final, start = result.final, result.start
    missing = []
    for name in result.added:
        params = final.config.effect(name).params()
        missing.append(
            {
                "name": name,
                "params": params,
                "uncertainty": {p: _finite(final.uncertainty(f"{name}.{p}")) for p in params},
                "spread": {p: result.spread(f"{name}.{p}") for p in params},
                "selection_frequency": result.frequency(f"add {name}"),
            }
        )
    superfluous = [
        {
            "name": name,
            "params": result.anchor.effect(name).params(),
            "uncertainty": {
                p: _finite(start.uncertainty(f"{name}.{p}"))
                for p in result.anchor.effect(name).params()
            },
        }
        for name in result.removed
    ]
    alternatives = [
        {"taken": s.taken, "frequency": s.frequency, "within_uncertainty": s.alternatives}
        for s in result.steps
        if s.kind == "forward" and s.taken is not None
    ]
    return {
        "verdict": result.verdict,
        "missing_effects": missing,
        "superfluous_effects": superfluous,
        "gap_before": {k: gaps["before"][k] for k in GAP_KEYS},
        "gap_after": {k: gaps["after"][k] for k in GAP_KEYS},
        "base_changes": base_changes(result),
        "at_bound": at_bound(result),
        "alternatives": alternatives,
        "rest": rest(result, data, sims["after"]),
        "policy": policy_dict(result.policy),
    }


def summary(report: dict, out: Path | str) -> str:
    """The one-line summary ``thruster-fdd discrepancy`` prints last."""
    named = ", ".join(m["name"] for m in report["missing_effects"]) or "none"
    extra = ", ".join(m["name"] for m in report["superfluous_effects"]) or "none"
    also = ""
    if report["base_changes"]:
        also += f"; base changed: {', '.join(c['change'] for c in report['base_changes'])}"
    for alt in report["alternatives"]:
        if alt["within_uncertainty"]:
            also += f"; undecided: {alt['taken']} or {', '.join(alt['within_uncertainty'])}"
    if report["rest"]["structured"]:
        kind = report["rest"]["kind"] or "of no kind the correction knows"
        also += f"; a structured rest is left ({kind})"
    return f"{report['verdict']}: missing {named}; superfluous {extra}{also}; report in {out}"


def markdown(result: Result, report: dict, data: Measured, plots: list[str]) -> str:
    """report.md: one page for a thruster engineer."""
    lines = ["# Discrepancy report", "", f"**Verdict: {result.verdict}.**", ""]
    if report["missing_effects"]:
        lines += [
            "## Missing effects",
            "",
            "| effect | parameter | value | std | fold spread | selected |",
            "|---|---|---|---|---|---|",
        ]
        for m in report["missing_effects"]:
            for p, v in m["params"].items():
                std = m["uncertainty"][p]
                lines.append(
                    f"| {m['name']} | {p} | {_fmt(v)} | {_fmt(std) if std is not None else '-'} | "
                    f"{_fmt(m['spread'][p])} | {m['selection_frequency']:.0%} |"
                )
        k_e = result.final.config.params.k_e
        for name, value in friction_currents(result.final.config).items():
            if name in result.added:
                lines.append(
                    f"\n`{name}` as motor current: {_fmt(value)} "
                    f"{FRICTION_UNITS[name][1]} (k_e {_fmt(k_e)} V s/rad)."
                )
        lines.append("")
    if report["superfluous_effects"]:
        lines += ["## Effects of the start the thruster lacks", ""]
        lines += [f"- `{m['name']}` (start: {m['params']})" for m in report["superfluous_effects"]]
        lines.append("")
    if report["base_changes"]:
        lines += ["## Base changes", ""]
        lines += [
            f"- {c['change']}: "
            + ", ".join(f"{k} {_fmt(float(v))}" for k, v in c["values"].items())
            for c in report["base_changes"]
        ]
        lines.append("")
    undecided = [a for a in report["alternatives"] if a["within_uncertainty"]]
    if undecided:
        lines += ["## Choices the data do not decide", ""]
        for a in undecided:
            others = ", ".join(f"{k} ({v:.0%})" for k, v in a["within_uncertainty"].items())
            lines.append(f"- `{a['taken']}` ({a['frequency']:.0%} of block resamples) or {others}")
        lines.append("")
    r = report["rest"]
    lines += ["## What is left", ""]
    if r["structured"]:
        where = "; ".join(
            f"{w['signal']} {w['region']} ({w['error_share']:.0%} of the error)" for w in r["where"]
        )
        lines.append(
            "A structured rest the vocabulary does not explain: "
            f"{r['kind'] or 'of no kind the correction knows'} (held-out variance "
            f"{r['score']:.2f} noise variances)."
            f" Where: {where}."
        )
    else:
        lines.append("Nothing the generic correction could explain on held-out data: noise.")
    lines += [
        f"Cues: {'; '.join(r['cues'])}.",
        "",
        "## Gap on held-out data",
        "",
        "| model | rpm RMSE | rpm R2 | current RMSE A | current R2 |",
        "|---|---|---|---|---|",
    ]
    for label, g in (("start", report["gap_before"]), ("final", report["gap_after"])):
        lines.append(
            f"| {label} | {g['rpm_rmse']:.1f} | {g['rpm_r2']:.4f} | "
            f"{g['current_rmse']:.3f} | {g['current_r2']:.4f} |"
        )
    lines += ["", f"Policy: {report['policy']}; noise std {data.sigma}.", ""]
    lines += [f"![{p}]({p})" for p in plots] + [""]
    return "\n".join(lines)


def details(result: Result, data: Measured, sims: dict, gaps: dict) -> dict:
    """details.json: every step with every move judged, signatures and regions."""
    return {
        "warnings": list(result.warnings),
        "reporting_floor_rpm": data.rpm_floor,
        "floor_zeroes_current": data.floor_zeroes_current,
        "noise_std": data.sigma,
        "steps": [
            {
                "kind": s.kind,
                "taken": s.taken,
                "frequency": s.frequency,
                "alternatives": s.alternatives,
                "moves": [
                    {f.name: getattr(j, f.name) for f in fields(j) if f.name != "d"}
                    for j in s.judged
                ],
            }
            for s in result.steps
        ],
        "signatures_before": signatures(sims["before"], data),
        "signatures_after": signatures(sims["after"], data),
        "regions_before": [r.__dict__ for r in regions(sims["before"], data, data.held)],
        "regions_after": [r.__dict__ for r in regions(sims["after"], data, data.held)],
        "gap_score_before": gaps["before"]["score"],
        "gap_score_after": gaps["after"]["score"],
        "fitted": dict(zip(result.final.names, result.final.values.tolist(), strict=True)),
    }


def write_report(result: Result, data: Measured, out: str | Path) -> dict:
    """Write report.json, model.yaml, report.md, details.json and PNG plots into ``out``, which
    is replaced only when all of them are complete (``core.atomic.replaced_dir``).

    Returns
    -------
    dict
        The report.json mapping.
    """
    out = Path(out)
    check_out_dir(out)
    sims = simulations(result, data)
    gaps = gaps_of(sims, data)
    report = report_json(result, data, sims, gaps)
    with replaced_dir(out) as stage:
        plots = _plots(data, sims, stage)
        write_text(stage / "report.json", json_text(report, nonfinite=lambda _x: None, indent=2))
        dump_config(result.final.config, stage / "model.yaml")
        write_text(stage / "report.md", markdown(result, report, data, plots))
        detail = json_text(details(result, data, sims, gaps), nonfinite=lambda _x: None, indent=2)
        write_text(stage / "details.json", detail)
    return report
