"""``fleet report``: one static HTML page (plots embedded as PNG, no server) and a Markdown
summary of a fleet dataset, plus ``summary.json`` with the same findings for scripts."""

from __future__ import annotations

import base64
import html
import io
import json
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from thruster_fdd.core.atomic import write_text
from thruster_fdd.core.labels import FAULT_CLASSES
from thruster_fdd_shore.core.fleet.dataset import read_dataset
from thruster_fdd_shore.core.fleet.scan import ERROR_THRUSTER
from thruster_fdd_shore.core.fleet.trends import DEFAULT_ALPHA, TEST_NAME, find_trends

FAULT_SHARE = 0.2
"""Share of a recording's time in fault labels from which the recording counts as showing the
fault (a fault published for a moment is listed with its share but not counted)."""


def _seconds(values: list[Any]) -> np.ndarray:
    return np.array([np.nan if v is None else v.timestamp() for v in values], dtype=float)


def summarize(table: Any, alpha: float = DEFAULT_ALPHA) -> dict[str, Any]:
    """The findings of a dataset table (``dataset.read_dataset``).

    Returns
    -------
    dict
        ``units`` ({``vehicle/thruster``: {"t_s", "eff_q10", "eff_q50", "eff_q90",
        "fault_prob"}} lists per recording, times s since the epoch), ``trends`` (per unit,
        ``trends.Trend`` as a dict), ``faults`` (per unit the first recording showing a fault:
        label, recording, time, share), ``failed`` (recordings with an error), ``test``,
        ``alpha``, counts.
    """
    rows = table.to_pylist()
    failed = [
        {"vehicle": r["vehicle"], "recording": r["recording"], "error": r["error"]}
        for r in rows
        if r["error"]
    ]
    good = [r for r in rows if not r["error"] and r["thruster"] != ERROR_THRUSTER]
    units: dict[str, dict[str, list[float]]] = {}
    faults: dict[str, dict[str, Any]] = {}
    for r in good:
        key = f"{r['vehicle']}/{r['thruster']}"
        u = units.setdefault(key, {k: [] for k in ("t_s", "eff_q10", "eff_q50", "eff_q90")})
        u.setdefault("fault_prob", [])
        u["t_s"].append(r["start"].timestamp())
        for k in ("eff_q10", "eff_q50", "eff_q90"):
            u[k].append(np.nan if r[k] is None else r[k])
        u["fault_prob"].append(np.nan if r["fault_prob_mean"] is None else r["fault_prob_mean"])
        share = sum(r[f"frac_{c}"] or 0.0 for c in FAULT_CLASSES)
        if key not in faults and r["first_fault_label"] and share >= FAULT_SHARE:
            faults[key] = {
                "label": r["first_fault_label"],
                "recording": r["recording"],
                "first_published": r["first_fault"].isoformat(),
                "date": r["start"].date().isoformat(),
                "share": share,
            }
    series = {k: (np.array(u["t_s"]), np.array(u["eff_q50"])) for k, u in units.items()}
    trends = find_trends(series, alpha)
    return {
        "test": TEST_NAME,
        "alpha": alpha,
        "tested": len(trends),
        "recordings": len({r["digest"] for r in rows}),
        "rows": len(rows),
        "units": units,
        "trends": {k: asdict(v) for k, v in sorted(trends.items())},
        "faults": dict(sorted(faults.items())),
        "failed": failed,
    }


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _plots(summary: dict[str, Any]) -> list[tuple[str, str]]:
    """(vehicle, base64 PNG) of each vehicle: effectiveness and fault probability over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.dates as mdates
    import matplotlib.pyplot as plt

    by_vehicle: dict[str, list[str]] = {}
    for key in summary["units"]:
        by_vehicle.setdefault(key.split("/")[0], []).append(key)
    out = []
    for vehicle, keys in sorted(by_vehicle.items()):
        fig, (ax_e, ax_p) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
        for key in sorted(keys):
            u = summary["units"][key]
            when = [datetime.fromtimestamp(t, UTC) for t in u["t_s"]]
            flag = summary["trends"].get(key, {}).get("flagged", False)
            name = key.split("/")[1] + (" (trend)" if flag else "")
            line = ax_e.plot(when, u["eff_q50"], "o-", ms=3, label=name)[0]
            ax_e.fill_between(when, u["eff_q10"], u["eff_q90"], color=line.get_color(), alpha=0.15)
            ax_p.plot(when, u["fault_prob"], "o-", ms=3, color=line.get_color())
        ax_e.set_ylabel("effectiveness\n(median, 10-90 %)")
        ax_p.set_ylabel("fault probability\n(mean per recording)")
        ax_p.set_ylim(-0.02, 1.02)
        ax_e.legend(loc="lower left", fontsize=8)
        ax_e.set_title(vehicle)
        ax_p.xaxis.set_major_formatter(mdates.DateFormatter("%Y-%m-%d"))
        fig.autofmt_xdate()
        out.append((vehicle, _png(fig)))
        plt.close(fig)
    return out


def _tables(summary: dict[str, Any]) -> dict[str, tuple[list[str], list[list[str]]]]:
    trends = [
        [
            key,
            str(t["n"]),
            f"{t['slope_per_30d']:+.3f}",
            f"{t['z']:+.2f}",
            f"{t['p']:.2g}",
            "**yes**" if t["flagged"] else "no",
        ]
        for key, t in summary["trends"].items()
    ]
    faults = [
        [key, f["label"], f["date"], f["recording"], f"{f['share']:.0%}"]
        for key, f in summary["faults"].items()
    ]
    failed = [[f["vehicle"], f["recording"], f["error"]] for f in summary["failed"]]
    return {
        "Trends": (["thruster", "recordings", "slope / 30 d", "z", "p", "flagged"], trends),
        "Faults and their first recording": (
            ["thruster", "fault", "date", "recording", "share of time"],
            faults,
        ),
        "Recordings that failed": (["vehicle", "recording", "error"], failed),
    }


def _intro(summary: dict[str, Any]) -> str:
    m = max(summary["tested"], 1)
    return (
        f"{summary['recordings']} recordings, {summary['rows']} rows, {summary['tested']} "
        f"thrusters tested for a trend. Test: {summary['test']} on the per-recording median "
        f"effectiveness over calendar time; a thruster is flagged when p < alpha / m = "
        f"{summary['alpha']:g} / {m} = {summary['alpha'] / m:.2g}, so the chance of any "
        f"false flag in the fleet (no trend anywhere, independent recordings) is at most "
        f"{summary['alpha']:g}. A recording shows a fault when fault labels cover at least "
        f"{FAULT_SHARE:.0%} of its time."
    )


def markdown(summary: dict[str, Any]) -> str:
    """The Markdown summary."""
    lines = ["# Fleet health", "", _intro(summary), ""]
    for title, (head, rows) in _tables(summary).items():
        lines += [f"## {title}", ""]
        if not rows:
            lines += ["none", ""]
            continue
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in rows]
        lines.append("")
    return "\n".join(lines)


def page(summary: dict[str, Any]) -> str:
    """The static HTML page with the plots embedded."""
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>Fleet health</title>",
        "<style>body{font-family:sans-serif;max-width:1000px;margin:auto}"
        "table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:2px 6px}</style>",
        "</head><body><h1>Fleet health</h1>",
        f"<p>{html.escape(_intro(summary))}</p>",
    ]
    for vehicle, png in _plots(summary):
        parts.append(f"<h2>{html.escape(vehicle)}</h2>")
        parts.append(f"<img alt='{html.escape(vehicle)}' src='data:image/png;base64,{png}'>")
    for title, (head, rows) in _tables(summary).items():
        parts.append(f"<h2>{html.escape(title)}</h2>")
        if not rows:
            parts.append("<p>none</p>")
            continue
        parts.append("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head))
        for row in rows:
            cells = (html.escape(c.replace("**", "")) for c in row)
            parts.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
        parts.append("</table>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _no_nan(value: Any) -> Any:
    """``value`` with NaN as None (strict JSON)."""
    if isinstance(value, dict):
        return {k: _no_nan(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_no_nan(v) for v in value]
    if isinstance(value, float | np.floating):
        return None if not np.isfinite(value) else float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def write_report(dataset: Path, out: Path, alpha: float = DEFAULT_ALPHA) -> dict[str, Any]:
    """Write ``out/index.html``, ``out/summary.md`` and ``out/summary.json``; the summary."""
    summary = summarize(read_dataset(dataset), alpha)
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "index.html", page(summary))
    write_text(out / "summary.md", markdown(summary))
    write_text(out / "summary.json", json.dumps(_no_nan(summary), indent=1) + "\n")
    return summary
