"""Replay of recordings, without ROS: what to publish, and how to judge what came back.

A recording's telemetry is replayed at the nominal model's sample time (the same decimation as
``nominal.residuals``), so every published sample produces exactly one residual and the replayer
can wait for it: no sample is dropped however fast the replay, and the same bag always gives
the same diagnoses. Expectations are the diagnoses recorded in the bag (a live run), or the
ground-truth labels a simulated recording carries in its metadata.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from thruster_fdd.core.errors import BadInputError, PartialInputWarning
from thruster_fdd.core.nominal.residuals import decimate
from thruster_fdd.core.traces.data import Trace
from thruster_fdd.core.traces.mcap_io import DECODE_ERRORS, METADATA_NAME, ORIGIN_KEY
from thruster_fdd.core.traces.mcap_read import read_mcap, ros2_decoder, warn_if_damaged


@dataclass(frozen=True)
class ThrusterBag:
    """One thruster's part of a recording.

    Attributes
    ----------
    thruster_id : str
        The id in its topic names.
    stamps_ns : tuple of int
        Header stamps of the telemetry samples to replay, ns, increasing.
    raw : tuple of bytes
        Their CDR bytes, as recorded.
    recorded : tuple of (float, str)
        Diagnoses recorded live: (header stamp s, label).
    truth : tuple of (float, str)
        Ground-truth label segments (start s, class) from simulation metadata; empty if none.
    used_residuals : bool
        The samples are those of the recorded residuals (the live model's), not a decimation.
    """

    thruster_id: str
    stamps_ns: tuple[int, ...]
    raw: tuple[bytes, ...]
    recorded: tuple[tuple[float, str], ...]
    truth: tuple[tuple[float, str], ...]
    used_residuals: bool = False

    def truth_at(self, t_s: float) -> str | None:
        """The ground-truth class at time ``t_s``, or None when the bag has none."""
        label = None
        for start, name in self.truth:
            if t_s >= start - 1e-9:
                label = name
        return label


_TOPIC = re.compile(r"^/thruster/(?P<id>[^/]+)/(?P<kind>esc/telemetry|fdd/residual|fdd/diagnosis)$")


_TYPES = {
    "esc/telemetry": "thruster_fdd_msgs/msg/EscTelemetry",
    "fdd/residual": "thruster_fdd_msgs/msg/Residual",
    "fdd/diagnosis": "thruster_fdd_msgs/msg/Diagnosis",
}


def load_bag(path: str | Path, period_s: float) -> tuple[ThrusterBag, ...]:
    """Read the telemetry to replay and the diagnoses of every thruster.

    The samples replayed are those the live nominal model used — the stamps of the recorded
    residuals — when the recording has residuals, so a live run is reproduced sample for
    sample; otherwise the telemetry decimated to ``period_s``. A damaged recording gives what
    can be read, with one ``DamagedRecordingWarning`` (``core.traces.mcap_read``).

    Raises
    ------
    BadInputError
        If the file is not an MCAP recording or holds no readable
        ``/thruster/<id>/esc/telemetry`` messages.
    """
    contents = read_mcap(path)
    path = contents.path
    telemetry: dict[str, list[tuple[int, bytes]]] = {}
    recorded: dict[str, list[tuple[float, str]]] = {}
    used: dict[str, set[int]] = {}
    meta = contents.metadata.get(METADATA_NAME, {})
    truth = {k.removeprefix("labels."): v for k, v in meta.items() if k.startswith("labels.")}
    problems: list[str] = []
    skipped: dict[str, int] = {}
    decoders: dict[int, Callable[[bytes], Any] | None] = {}
    for cid, _, data in contents.messages:
        channel = contents.channels.get(cid)
        match = None if channel is None else _TOPIC.match(channel.topic)
        if channel is None or match is None:
            continue
        if cid not in decoders:
            usable = channel.schema is not None and channel.schema.name == _TYPES[match["kind"]]
            decoders[cid] = ros2_decoder(channel) if usable else None
        decode = decoders[cid]
        if decode is None:
            skipped[channel.topic] = skipped.get(channel.topic, 0) + 1
            continue
        try:
            decoded = decode(data)
            ns = decoded.header.stamp.sec * 1_000_000_000 + decoded.header.stamp.nanosec
            label = str(decoded.label) if match["kind"] == "fdd/diagnosis" else ""
        except DECODE_ERRORS:
            skipped[channel.topic] = skipped.get(channel.topic, 0) + 1
            continue
        tid = match["id"]
        if match["kind"] == "esc/telemetry":
            telemetry.setdefault(tid, []).append((ns, data))
        elif match["kind"] == "fdd/residual":
            used.setdefault(tid, set()).add(ns)
        else:
            # The same float as the replayer's stamp_ns * 1e-9, so equal stamps compare equal.
            recorded.setdefault(tid, []).append((ns * 1e-9, label))
    problems += [
        f"{topic}: {n} message(s) of another type or not decodable, skipped"
        for topic, n in skipped.items()
    ]
    warn_if_damaged(contents, tuple(problems))
    if not telemetry:
        raise BadInputError(f"{path}: no readable /thruster/<id>/esc/telemetry messages to replay")
    bags = []
    for tid, samples in sorted(telemetry.items()):
        samples.sort(key=lambda s: s[0])
        unique = [s for i, s in enumerate(samples) if i == 0 or s[0] > samples[i - 1][0]]
        if tid in used:
            keep = np.array([s[0] in used[tid] for s in unique])
        else:
            keep = decimate(np.array([s[0] for s in unique], dtype=float) * 1e-9, period_s)
        if not keep.any():
            raise BadInputError(f"{path}: thruster {tid} has no sample to replay")
        bags.append(
            ThrusterBag(
                thruster_id=tid,
                stamps_ns=tuple(s[0] for s, k in zip(unique, keep, strict=True) if k),
                raw=tuple(s[1] for s, k in zip(unique, keep, strict=True) if k),
                recorded=tuple(recorded.get(tid, [])),
                truth=_segments(path, truth.get(tid, "")),
                used_residuals=tid in used,
            )
        )
    return tuple(bags)


def _segments(path: Path, text: str) -> tuple[tuple[float, str], ...]:
    """Ground-truth label segments (start s, class) of ``labels.<id>`` metadata."""
    try:
        return tuple(
            (float(start), name)
            for start, _, name in (part.partition(":") for part in text.split(";") if part)
        )
    except ValueError:
        raise BadInputError(
            f"{path}: label metadata {text[:60]!r} is not start_s:class;..."
        ) from None


def collapse(labels: list[str]) -> list[str]:
    """The sequence of distinct consecutive labels (``a a b b a`` -> ``a b a``)."""
    return [label for i, label in enumerate(labels) if i == 0 or label != labels[i - 1]]


@dataclass(frozen=True)
class ReplayCheck:
    """How a replay's diagnoses compare with the expectations of one thruster.

    Attributes
    ----------
    thruster_id : str
    decisions : int
        Diagnoses published during the replay.
    sequence : list of str
        The replay's collapsed label sequence (``unknown`` dropped).
    expected_sequence : list of str or None
        The recorded (or ground-truth) collapsed sequence; None when the bag has neither.
    source : str
        ``recorded``, ``truth`` or ``none``.
    agreement : float or None
        Fraction of replayed decisions equal to the expectation, ``unknown`` included:
        recorded — the live decision of the same window (the same header stamp, the window's
        last sample); a replayed decision of a window the live run did not decide counts as a
        disagreement, so a replay whose windows are shifted against the live ones fails;
        ground truth — the class at its time, decisions within ``settle_s`` after a label
        change and ``unknown`` ones not counted.
    passed : bool
        Sequences equal and agreement at least the threshold (True when nothing is expected).
    """

    thruster_id: str
    decisions: int
    sequence: list[str]
    expected_sequence: list[str] | None
    source: str
    agreement: float | None
    passed: bool


def _same_window_pairs(
    expected: list[tuple[float, str]], got: list[tuple[float, str]]
) -> list[tuple[str | None, str]]:
    """(recorded, replayed) labels of every replayed decision, paired by the stamp of its
    window's last sample (a Diagnosis' header stamp); recorded None when the recording has no
    decision of that window (the replay's windows are not the live ones)."""
    by_stamp = {round(t, 6): label for t, label in expected}
    return [(by_stamp.get(round(t, 6)), label) for t, label in got]


def check_replay(
    bag: ThrusterBag,
    got: list[tuple[float, str]],
    *,
    min_agreement: float = 0.9,
    settle_s: float = 15.0,
) -> ReplayCheck:
    """Compare replayed diagnoses ``got`` (stamp s, label) with what ``bag`` expects."""
    labels = [label for _, label in got if label != "unknown"]
    sequence = collapse(labels)
    if bag.recorded:
        expected = [(t, label) for t, label in bag.recorded]
        exp_labels = collapse([label for _, label in expected if label != "unknown"])
        pairs = _same_window_pairs(expected, got)
        agreement = sum(1 for a, b in pairs if a == b) / len(pairs) if pairs else 0.0
        passed = sequence == exp_labels and agreement >= min_agreement
        return ReplayCheck(
            bag.thruster_id, len(got), sequence, exp_labels, "recorded", agreement, passed
        )
    if bag.truth:
        changes = [start for start, _ in bag.truth[1:]]
        counted = [
            (bag.truth_at(t), label)
            for t, label in got
            if not any(0.0 <= t - c < settle_s for c in changes) and label != "unknown"
        ]
        agreement = sum(1 for a, b in counted if a == b) / len(counted) if counted else 0.0
        exp_labels = collapse([name for _, name in bag.truth])
        passed = sequence == exp_labels and agreement >= min_agreement
        return ReplayCheck(
            bag.thruster_id, len(got), sequence, exp_labels, "truth", agreement, passed
        )
    return ReplayCheck(bag.thruster_id, len(got), sequence, None, "none", None, True)


SAME_SAMPLE_S = 1e-5
"""A trace time and a stamp this close (s) are the same sample (far below the ESC period)."""


def live_samples(trace: Trace, files: list[Path], period_s: float) -> Trace:
    """The samples of ``trace`` (read from the recording ``files``) that ``replay`` publishes:
    those the live nominal model used (``load_bag``), so ``diagnose`` and ``replay`` decide on
    the same windows as the live run. The trace unchanged when the recording has no residuals
    of its thruster (a simulated recording: the decimation is then the same in both).

    Parameters
    ----------
    trace : Trace
        One thruster's telemetry read from ``files`` (times relative to the recording's
        ``time_origin_ns``, 0 for a live recording).
    files : list of Path
        The recording's MCAP files, in order.
    period_s : float
        The nominal model's sample time, s.
    """
    stamps: set[int] = set()
    origin_ns = 0
    for file in files:
        # The trace's own reading warned about damage and skipped splits already.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PartialInputWarning)
            try:
                contents = read_mcap(file)
                bags = load_bag(file, period_s)
            except BadInputError:
                continue
        origin_ns = int(contents.metadata.get(METADATA_NAME, {}).get(ORIGIN_KEY, "0") or 0)
        for bag in bags:
            if bag.thruster_id == trace.thruster_id and bag.used_residuals:
                stamps.update(bag.stamps_ns)
    if not stamps:
        return trace
    # Nearest stamp within 10 us: the trace's float times lose the last digits of the ns.
    wanted = np.array(sorted((ns - origin_ns) * 1e-9 for ns in stamps))
    i = np.clip(np.searchsorted(wanted, trace.t), 1, len(wanted) - 1) if len(wanted) > 1 else 0
    near = np.minimum(np.abs(wanted[i] - trace.t), np.abs(wanted[i - 1] - trace.t))
    keep = near <= SAME_SAMPLE_S
    return Trace(
        t=trace.t[keep],
        command=trace.command[keep],
        voltage=trace.voltage[keep],
        rpm=trace.rpm[keep],
        current=trace.current[keep],
        condition=trace.condition,
        thruster_id=trace.thruster_id,
        extra={k: v[keep] for k, v in trace.extra.items()},
        labels=None if trace.labels is None else trace.labels[keep],
    )
