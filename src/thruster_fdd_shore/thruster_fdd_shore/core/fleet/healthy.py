"""``fleet dataset --healthy``: the healthy stretches of every unit, as trace CSVs ready for
``thruster-fdd train nominal``.

A stretch is a span of a recording over which the published label was one of the nominal
classes, at least ``min_s`` long, in a recording without a fault published and whose
effectiveness (10 % quantile) is at least ``min_effectiveness``; a unit fouling slowly is left
out from the day its thrust starts to fall, before the classifier calls it. Each stretch is
written as ``OUT/<vehicle>/<thruster>/<recording stem>_<offset s>.csv`` with its samples (times
from the recording's first sample, s) and the published nominal class as ``condition``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES, FAULT_CLASSES
from thruster_fdd_shore.core.fleet.archive import read_recording
from thruster_fdd_shore.core.fleet.compare import parse_events
from thruster_fdd_shore.core.traces.csv_io import write_trace_csv

NOMINAL = tuple(c for c in CLASS_NAMES if c not in FAULT_CLASSES)
"""The healthy classes."""


@dataclass(frozen=True)
class Stretch:
    """A healthy span of one thruster's recording.

    Attributes
    ----------
    vehicle, thruster, recording : str
        Whose, and the recording relative to the archive.
    start_s, end_s : float
        From the recording's first sample of that thruster, s.
    label : str
        The published nominal class.
    """

    vehicle: str
    thruster: str
    recording: str
    start_s: float
    end_s: float
    label: str


def stretches(
    rows: list[dict[str, Any]], *, min_s: float = 30.0, min_effectiveness: float = 0.9
) -> list[Stretch]:
    """Healthy stretches of dataset rows (``dataset.as_rows``)."""
    out = []
    for r in rows:
        if r.get("error") or r.get("first_fault_label"):
            continue
        if r.get("eff_q10") is None or r["eff_q10"] < min_effectiveness:
            continue
        events = parse_events(r["events"])
        ends = [t for t, _ in events[1:]] + [float(r["duration_s"] or 0.0)]
        for (t0, label), t1 in zip(events, ends, strict=True):
            if label in NOMINAL and t1 - t0 >= min_s:
                out.append(Stretch(r["vehicle"], r["thruster"], r["recording"], t0, t1, label))
    return out


def write_stretches(archive: Path, found: list[Stretch], out: Path) -> list[Path]:
    """Cut each stretch from its recording and write it as a trace CSV; the files written.

    Raises
    ------
    BadInputError
        If a recording is gone or no longer holds the thruster.
    """
    written = []
    by_recording: dict[str, list[Stretch]] = {}
    for s in found:
        by_recording.setdefault(s.recording, []).append(s)
    for rel, items in sorted(by_recording.items()):
        traces = {t.thruster_id: t for t in read_recording(archive / rel).traces}
        for s in items:
            trace = traces.get(s.thruster)
            if trace is None:
                raise BadInputError(f"{archive / rel}: no thruster {s.thruster!r} any more")
            t = trace.t - trace.t[0]
            keep = np.flatnonzero((t >= s.start_s) & (t <= s.end_s))
            piece = replace(
                trace,
                t=t[keep],
                command=trace.command[keep],
                voltage=trace.voltage[keep],
                rpm=trace.rpm[keep],
                current=trace.current[keep],
                extra={k: v[keep] for k, v in trace.extra.items()},
                labels=None,
                condition=s.label,
            )
            stem = Path(rel).name.removesuffix(".mcap")
            path = out / s.vehicle / s.thruster / f"{stem}_{s.start_s:.0f}s.csv"
            write_trace_csv(piece, path)
            written.append(path)
    return written
