"""``fleet compare``: where a new model pair would have published something else than the pair
that scanned the archive, recording by recording and thruster by thruster.

Both pairs' published labels are step functions of time (a row's ``events``); the comparison
is the share of the recording's time on which they differ, and whether the first fault (label
and the time it is first published) differs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

NONE = "-"
"""The label before the first decision (nothing published yet)."""


def parse_events(text: str | None) -> list[tuple[float, str]]:
    """``offset_s:label;...`` -> [(offset s, label)]."""
    out = []
    for part in (text or "").split(";"):
        if part:
            t, _, label = part.rpartition(":")
            out.append((float(t), label))
    return out


def label_at(events: list[tuple[float, str]], t: np.ndarray) -> np.ndarray:
    """The published label at each time of ``t`` (s from the start), shape (n,)."""
    if not events:
        return np.full(len(t), NONE, dtype=object)
    times = np.array([e[0] for e in events])
    labels = np.array([NONE] + [e[1] for e in events], dtype=object)
    return labels[np.searchsorted(times, t, side="right")]


def disagreement(a: str | None, b: str | None, duration_s: float) -> float:
    """Share of ``[0, duration_s]`` on which two label timelines differ (0..1)."""
    ea, eb = parse_events(a), parse_events(b)
    cuts = sorted({0.0, duration_s, *(t for t, _ in ea + eb if 0.0 <= t <= duration_s)})
    if duration_s <= 0 or len(cuts) < 2:
        return 0.0
    edges = np.array(cuts)
    mids = 0.5 * (edges[:-1] + edges[1:])
    differ = label_at(ea, mids) != label_at(eb, mids)
    return float(np.sum(np.diff(edges)[differ]) / duration_s)


@dataclass(frozen=True)
class Difference:
    """One recording and thruster on which the two pairs differ.

    Attributes
    ----------
    vehicle, thruster, recording : str
        Which.
    share : float
        Share of the recording's time with different published labels.
    old_fault, new_fault : str
        First fault of each pair (``""`` for none) with its offset from the start, s.
    """

    vehicle: str
    thruster: str
    recording: str
    share: float
    old_fault: str
    new_fault: str


def _fault(row: dict[str, Any]) -> str:
    if not row.get("first_fault_label"):
        return ""
    return f"{row['first_fault_label']}@{row['first_fault_s'] - row['start_s']:.0f}s"


def differences(
    old: list[dict[str, Any]], new: list[dict[str, Any]], tolerance: float = 0.0
) -> tuple[list[Difference], int]:
    """Rows on which a new scan differs from the old one (by recording digest and thruster).

    Parameters
    ----------
    old, new : list of dict
        Rows with ``digest``, ``thruster``, ``events``, ``duration_s``, ``start_s``,
        ``first_fault_label``, ``first_fault_s`` (times in s since the epoch).
    tolerance : float
        Share of time the labels may differ without counting, when the first fault agrees.

    Returns
    -------
    (list of Difference, int)
        The differences and the number of rows compared.
    """
    by_key = {(r["digest"], r["thruster"]): r for r in old if not r.get("error")}
    out, compared = [], 0
    for r in new:
        o = by_key.get((r["digest"], r["thruster"]))
        if o is None or r.get("error"):
            continue
        compared += 1
        share = disagreement(o["events"], r["events"], float(o["duration_s"] or 0.0))
        fo, fn = _fault(o), _fault(r)
        if share > tolerance or fo.partition("@")[0] != fn.partition("@")[0]:
            out.append(Difference(r["vehicle"], r["thruster"], r["recording"], share, fo, fn))
    return out, compared
