"""The discrepancy report files of ``thruster-fdd discrepancy``.

``write_report`` writes report.json, model.yaml, report.md, details.json and the PNG plots into
a staging folder that replaces the output folder only once everything is written
(``core.atomic.replaced_dir``); ``check_out_dir`` refuses an output folder that holds anything
else, before the workflow runs.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from thruster_fdd.core.atomic import replaced_dir, write_text
from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.core.discrepancy.fit import BASE_FIT, BASE_RANGE, Fit
from thruster_fdd_shore.core.discrepancy.measure import (
    FOLDS,
    Measured,
    describe,
    regions,
    reported,
    signatures,
    simulate_model,
    weighted_residuals,
)
from thruster_fdd_shore.core.discrepancy.search import (
    AT_BOUND,
    BASE_GAIN,
    BIC_EVIDENCE,
    CONTRADICTED,
    MIN_GAIN,
    SAME_CHOICE,
    STRUCTURED,
    Candidate,
    Result,
    Round,
)
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


def _is_chosen(c: Candidate, rnd: Round) -> bool:
    """Whether candidate ``c`` is the one round ``rnd`` took: accepted, and re-fitted with the
    base change it was taken with (an effect may be tried alone and with one)."""
    joint = c.joint.label if c.joint else None
    return c.accepted and c.name == rnd.chosen and joint == rnd.chosen_with


def _gap_rows(label: str, fit: Fit) -> str:
    g = fit.gap
    return (
        f"| {label} | {g.rpm_rmse:.1f} | {g.rpm_r2:.4f} | {g.current_rmse:.3f} | "
        f"{g.current_r2:.4f} | {g.voltage_rmse:.3f} | {g.score:.2f} |"
    )


def _base_rows(result: Result) -> list[str]:
    """Fitted base and structural terms of the final model against the start."""
    start = result.start.config
    rows = ["| parameter | start (calibrated) | final | std |", "|---|---|---|---|"]
    for key, value, std in zip(
        result.final.names, result.final.values, result.final.std, strict=True
    ):
        owner, name = key.split(".")
        if owner not in ("params", "structure"):
            continue
        before = getattr(start.params if owner == "params" else start.structure, name)
        rows.append(
            f"| {key} | {_fmt(float(before))} | {_fmt(float(value))} | {_fmt(float(std))} |"
        )
    return rows


def at_bound(result: Result) -> list[str]:
    """Base parameters of the final model on their calibration bound, described."""
    if result.anchor is None:
        return []
    out = []
    for key, value in zip(result.final.names, result.final.values, strict=True):
        owner, name = key.split(".")
        if owner != "params" or name not in BASE_FIT or name == "i_idle_a":
            continue
        ref = float(getattr(result.anchor.params, name))
        factor = result.ranges.get(key, BASE_RANGE)
        if abs(math.log(value / ref)) >= math.log(factor) - AT_BOUND:
            out.append(f"{name} {_fmt(float(value))} (start {_fmt(ref)}, bound x{factor:g})")
    return out


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


def _friction_currents(result: Result) -> list[str]:
    """report.md lines: each named friction as the current it draws (``friction_currents``)."""
    k_e = result.final.config.params.k_e
    out = [
        f"- `{name}` as motor current: {FRICTION_UNITS[name][0]} / k_e = {_fmt(value)} "
        f"{FRICTION_UNITS[name][1]} (k_e {_fmt(k_e)} V s/rad); the better-determined figure "
        "when k_e is not fixed by the data."
        for name, value in friction_currents(result.final.config).items()
        if name in result.added
    ]
    return ["", *out] if out else []


def _undecided(result: Result) -> list[str]:
    """report.md lines: the rounds in which another candidate fitted about as well as the one
    taken (``Round.rivals``)."""
    rows = []
    for k, rnd in enumerate(result.rounds, 1):
        taken = next((f for f in rnd.finals if f[0] == rnd.chosen), None)
        if taken is None:
            continue
        for name, _held, score, bic in rnd.rivals:
            rows.append(
                f"| {k} | `{rnd.chosen}` | {taken[2]:.2f} / {taken[3]:.1f} | `{name}` | "
                f"{score:.2f} / {bic:.1f} |"
            )
    if not rows:
        return []
    return [
        "",
        "## Choices the data do not decide",
        "",
        f"In these rounds another candidate fitted the held-out data (cross-validated over "
        f"{len(FOLDS)} folds) within {100 * SAME_CHOICE:g} % of the one taken, and the BIC "
        "decided (a widened bound first). The thruster may hold the other instead; a run that "
        "excites where the two differ, or a bench measurement of what they change, would tell.",
        "",
        "| round | taken | cross-validated score / BIC | as good | cross-validated score / BIC |",
        "|---|---|---|---|---|",
        *rows,
    ]


def markdown(result: Result, data: Measured, sims: dict[str, dict], plots: list[str]) -> str:
    """The report.md text."""
    rep = result.report()
    found = [f"missing: {', '.join(f'`{n}`' for n in result.added)}"] if result.added else []
    if rep["superfluous_effects"]:
        names = ", ".join(f"`{m['name']}`" for m in rep["superfluous_effects"])
        found.append(f"superfluous: {names}")
    lines = [
        "# Discrepancy report",
        "",
        f"**Verdict: `{rep['verdict']}`**" + (f" — {'; '.join(found)}" if found else ""),
        "",
    ]
    if result.final.gap.score > STRUCTURED:
        why = (
            "no candidate of the vocabulary explains it"
            if not result.rounds or result.rounds[-1].chosen is None
            else f"the search stopped after {len(result.rounds)} rounds"
        )
        lines += [
            f"The residual of the final model is still structured (held-out score "
            f"{result.final.gap.score:.1f} > {STRUCTURED:g}) and {why}: see where the final "
            "model disagrees, below.",
            "",
        ]
    edge = at_bound(result)
    if edge:
        lines += [
            "Base parameters on their calibration bound (the thruster differs from the start "
            f"there, or they make up for something else): {'; '.join(edge)}.",
            "",
        ]
    lines += [
        f"Samples: {len(data.t)} over {data.t[-1]:.0f} s; fit on {int(data.fit.sum())}, "
        f"held out {int(data.held.sum())} (interleaved blocks). Noise estimate: "
        f"rpm {data.sigma['rpm']:.3g}, current {data.sigma['current']:.3g} A, "
        f"voltage {data.sigma['voltage']:.3g} V. Reporting floor read from the data: "
        f"{data.rpm_floor:.0f} rpm{' (current zeroed too)' if data.floor_zeroes_current else ''}.",
        "",
    ]
    lines += [f"- warning: {w}" for w in result.warnings]
    lines += _undecided(result)
    lines += ["", "## Named missing effects", ""]
    if rep["missing_effects"]:
        lines += ["| effect | parameter | value | std |", "|---|---|---|---|"]
        for m in rep["missing_effects"]:
            for p, v in m["params"].items():
                lines.append(f"| `{m['name']}` | {p} | {_fmt(v)} | {_fmt(m['uncertainty'][p])} |")
        lines += _friction_currents(result)
    else:
        lines.append("none")
    lines += ["", "## Effects of the start the thruster lacks", ""]
    if result.superfluous:
        lines += [
            f"Each effect of the start the search did not name, fitted freely: superfluous when "
            f"the fit moves it more than {CONTRADICTED:g} standard deviations from the start's "
            f"value towards none (or all the way to none), the model re-fitted without it is "
            f"no worse (lower BIC, held-out score no higher) or what is left of it would not "
            f"be named missing, and held at the start's value it scores more than "
            f"{100 * SAME_CHOICE:g} % worse than without it. A dead time is removed also "
            f"with a second ESC stage in its place (the stage then a base change below).",
            "",
            "| effect | start | fitted (std) | ΔBIC without | held-out score with / without "
            "| superfluous |",
            "|---|---|---|---|---|---|",
        ]
        for t in result.superfluous:
            start = ", ".join(f"{k} {_fmt(v)}" for k, v in t.start_params.items())
            fitted = ", ".join(
                f"{_fmt(t.fitted[k])} ({_fmt(t.fitted_std[k])})" for k in t.start_params
            )
            without = t.without.gap.score if t.without is not None else math.nan
            lines.append(
                f"| `{t.name}` | {start} | {fitted} | {t.delta_bic:.1f} | "
                f"{t.score_with:.2f} / {without:.2f} | "
                f"{'yes' if t.superfluous else 'no'} |"
            )
    else:
        lines.append("the start holds no effect the search did not name")
    lines += ["", "## Base changes", ""]
    replaced = [
        f"{name} replaced by {rival} (re-chosen after a base change)"
        for name, rival in result.replaced
    ]
    lines += [f"- {n}" for n in (*result.base_changes, *replaced)] or ["none"]
    lines += ["", "### Base and structural terms", "", *_base_rows(result)]
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
        chosen = next((c for c in rnd.candidates if _is_chosen(c, rnd)), None)
        if chosen is not None:
            lines.append(_gap_rows(f"+ {chosen.label} (candidate re-fit)", chosen.fit))
    lines += [_gap_rows("final (calibrated)", result.final), ""]
    for k, rnd in enumerate(result.rounds, 1):
        lines += [
            f"## Round {k}: candidates",
            "",
            f"Accepted: ΔBIC < -{BIC_EVIDENCE:g} on the fit samples, and a held-out gain and an "
            f"own gain of at least {MIN_GAIN:g} (gain: the fraction of the excess over noise "
            f"removed; own gain: what taking the effect out of the re-fit again costs on the fit "
            f"samples); a widened bound that is not the round's best needs a held-out gain of "
            f"{BASE_GAIN:g}; an effect re-fitted with a base change must also gain on the effect "
            f"alone; when none passes and the held-out score is above {STRUCTURED:g}, an effect is "
            f"accepted whose pair with another passes and each part gains on the other alone "
            f"(docs/discrepancy.md, Method step 4).",
            "",
            "| effect | ΔBIC (fit) | held-out gain | own gain | held-out score | accepted |",
            "|---|---|---|---|---|---|",
        ]
        for c in sorted(rnd.candidates, key=lambda c: c.fit.gap.score):
            name = f"`{c.name}` + {c.joint.label}" if c.joint else f"`{c.name}`"
            lines.append(
                f"| {name} | {c.delta_bic:.1f} | {c.gain:.2f} | {c.own_gain:.2f} | "
                f"{c.fit.gap.score:.2f} | {'yes' if c.accepted else 'no'} |"
            )
        for p in rnd.pairs:
            lines.append(
                f"| `{p.lead}` with `{p.partner}` (pair) | {p.delta_bic:.1f} | {p.gain:.2f} | - | "
                f"{p.score:.2f} | {'yes: the lead' if p.accepted else 'no'} |"
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


REST_REGIONS = 2
"""Regions per signal listed in report.json's ``rest.where`` (the largest error shares)."""


def rest(result: Result, details: dict) -> dict:
    """What the final model leaves unexplained, for report.json's ``rest``, from the final
    model's signatures and regions in ``details`` (``write_report``'s details.json mapping).

    ``structured``: the held-out score (mean squared residual in noise-variance units) is above
    ``STRUCTURED``, so the residual is more than noise and the named effects do not account for
    the whole difference; ``cues``: the plain-language reading of the residual's signatures
    (``describe``); ``where``: the operating regions holding most of each signal's squared
    held-out residual (``regions`` lists them largest first).
    """
    keys = ("signal", "region", "error_share", "sample_share")
    where = [
        {k: r[k] for k in keys}
        for signal in ("rpm", "current")
        for r in [r for r in details["regions_after"] if r["signal"] == signal][:REST_REGIONS]
    ]
    score = result.final.gap.score
    return {
        "structured": bool(score > STRUCTURED),
        "score": score,
        "threshold": STRUCTURED,
        "cues": describe(details["signatures_after"]),
        "where": where,
    }


def report_json(result: Result, details: dict) -> dict:
    """The report.json mapping (docs/contracts.md): ``Result.report()`` plus the base changes
    the search adopted, the base parameters left on their bound, and the ``rest``, taken from
    ``details`` (``write_report``'s details.json mapping, computed once)."""
    return {
        **result.report(),
        "base_changes": details["base_changes"],
        "replaced": [{"effect": name, "by": rival} for name, rival in details["replaced"]],
        "at_bound": details["at_bound"],
        "rest": rest(result, details),
    }


def write_report(result: Result, data: Measured, out: str | Path) -> dict[str, Path]:
    """Write report.json, model.yaml, report.md, details.json and PNG plots into ``out``.

    The files are written into a staging folder beside ``out``, which replaces ``out`` only
    when all of them are complete (``core.atomic.replaced_dir``): a run that fails leaves what
    was there before. ``check_out_dir`` says which folders may be replaced.

    Returns
    -------
    dict of str to Path
        File kind -> written path.
    """
    out = Path(out)
    check_out_dir(out)
    sims = {
        "before": simulate_model(result.start.config, data),
        "after": simulate_model(result.final.config, data),
    }
    details = {
        "warnings": list(result.warnings),
        "reporting_floor_rpm": data.rpm_floor,
        "floor_zeroes_current": data.floor_zeroes_current,
        "base_changes": list(result.base_changes),
        "replaced": [list(pair) for pair in result.replaced],
        "at_bound": at_bound(result),
        "signatures_before": signatures(sims["before"], data),
        "signatures_after": signatures(sims["after"], data),
        "regions_before": [r.__dict__ for r in regions(sims["before"], data, data.held)],
        "regions_after": [r.__dict__ for r in regions(sims["after"], data, data.held)],
        "rounds": [
            {
                "chosen": rnd.chosen,
                "chosen_with": rnd.chosen_with,
                "pairs": [p.__dict__ for p in rnd.pairs],
                "finals": [
                    {"name": name, "held_out_score": held, "cv_score": score, "bic": bic}
                    for name, held, score, bic in rnd.finals
                ],
                "rivals": [name for name, *_ in rnd.rivals],
                "candidates": [
                    {
                        "name": c.name,
                        "with": c.joint.label if c.joint else None,
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
        "superfluous_tests": [
            {
                "name": t.name,
                "start_params": t.start_params,
                "fitted": t.fitted,
                "fitted_std": t.fitted_std,
                "contradicted": t.contradicted,
                "delta_bic_without": t.delta_bic,
                "held_out_score_without": t.without.gap.score if t.without else None,
                "base_change_without": t.change.label if t.change else None,
                "superfluous": t.superfluous,
            }
            for t in result.superfluous
        ],
        "gap_score_before": result.start.gap.score,
        "gap_score_after": result.final.gap.score,
        "fitted": dict(zip(result.final.names, result.final.values.tolist(), strict=True)),
    }
    with replaced_dir(out) as stage:
        plots = _plots(result, data, sims, stage)
        write_text(
            stage / "report.json",
            json_text(report_json(result, details), nonfinite=lambda _x: None, indent=2),
        )
        dump_config(result.final.config, stage / "model.yaml")
        write_text(stage / "report.md", markdown(result, data, sims, plots))
        write_text(stage / "details.json", json_text(details, nonfinite=lambda _x: None, indent=2))
    files = {
        name: out / name for name in ("report.json", "model.yaml", "report.md", "details.json")
    }
    files.update({p: out / p for p in plots})
    return files
