"""Replay of recordings, without ROS: what to publish, and how to judge what came back.

A recording's telemetry is replayed at the nominal model's sample time (the same decimation as
``nominal.residuals``), so every published sample produces exactly one residual and the replayer
can wait for it: no sample is dropped however fast the replay, and the same bag always gives
the same diagnoses. Expectations are the diagnoses recorded in the bag (a live run), or the
ground-truth labels a simulated recording carries in its metadata.

A live recording may begin mid-stream (a recorder started while the vehicle runs, or racing
its drivers), so its first decisions rest on samples it does not hold. ``align_bag`` finds
what a replay from fresh nodes can reproduce (docs/diagnosis.md, "Replaying a live
recording"):

- a decision's *window* part (its calibrated probabilities, ``covered`` and the window gate:
  ``low_excitation``, ``outside_training``, ``unlike_classes`` or informative) depends on the
  window's samples and the nominal model's state at them: in series-parallel mode the
  ``warmup_samples`` measured samples before each, in parallel mode everything since the
  model's last reset. It is comparable when all of that lies in the recording and the replay's
  window grid is the live one: the replay starts so that its first window is a recorded one;
- its *label* (with confidence, fault evidence and ``evidence_pending``) depends on every
  informative window since the classifier's decision layer started. It is comparable only when
  the recording holds that start too: the thruster's first recorded residual is the nominal
  model's first (flagged ``WARMING_UP``, not ``STATE_RESET``, which every warm-up after a
  reset carries, and followed by the rest of that warm-up), its telemetry is recorded, and
  no ``stale`` diagnosis (which restarts the live decision layer) came since.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from thruster_fdd.core.artifact import CARD_FILE
from thruster_fdd.core.diagnosis.model import read_classifier_card
from thruster_fdd.core.diagnosis.stream import (
    LOW_EXCITATION,
    OUTSIDE_TRAINING,
    UNLIKE_CLASSES,
    WindowFeaturizer,
)
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.nominal.card import read_nominal_card
from thruster_fdd.core.nominal.residuals import INPUT_INVALID, STATE_RESET, WARMING_UP, decimate
from thruster_fdd.core.traces.data import Trace
from thruster_fdd.core.traces.mcap_io import DECODE_ERRORS, METADATA_NAME, ORIGIN_KEY
from thruster_fdd.core.traces.mcap_read import read_mcap, ros2_decoder, warn_if_damaged
from thruster_fdd_shore.core.traces.files import is_bag, read_splits

WINDOW_REASONS = (LOW_EXCITATION, OUTSIDE_TRAINING, UNLIKE_CLASSES)
"""The reasons of an ``unknown`` that the window alone decides (its gate), not the evidence."""

BEFORE_RECORDING = "before_recording"
MISSING_SAMPLE = "missing_sample"
NOT_COMPARABLE_REASONS = {
    BEFORE_RECORDING: "its window, or the nominal model state it rests on, begins before the "
    "recording",
    MISSING_SAMPLE: "it comes after a sample the live model used that the recording lacks",
}
"""Why a recorded decision is not comparable (``Comparability.not_comparable``)."""

PROBABILITY_TOLERANCE = 1e-9
"""Largest difference of one class probability between the same window's two decisions."""


@dataclass(frozen=True)
class WindowDecision:
    """One diagnosis of a window, live or replayed, as it is compared.

    Attributes
    ----------
    stamp_ns : int
        Header stamp: the window's last sample, ns.
    label : str
        The published label.
    probabilities : tuple of float
        The window's calibrated probabilities, in the classifier's class order.
    covered : bool
        The window's operating point lies in the training region.
    reason : str
        Why ``label`` is ``unknown``; empty when it is a class.
    """

    stamp_ns: int
    label: str
    probabilities: tuple[float, ...] = ()
    covered: bool = True
    reason: str = ""

    @property
    def t_s(self) -> float:
        """The stamp in s."""
        return self.stamp_ns * 1e-9

    @property
    def gate(self) -> str:
        """The window's own reason to be ``unknown`` (``WINDOW_REASONS``), empty when the
        window is informative."""
        return self.reason if self.reason in WINDOW_REASONS else ""

    def same_window(self, other: WindowDecision) -> bool:
        """Whether ``other`` decided this window alike: probabilities within
        ``PROBABILITY_TOLERANCE``, the same coverage and gate."""
        return (
            len(self.probabilities) == len(other.probabilities)
            and all(
                abs(a - b) <= PROBABILITY_TOLERANCE
                for a, b in zip(self.probabilities, other.probabilities, strict=True)
            )
            and self.covered == other.covered
            and self.gate == other.gate
        )


@dataclass(frozen=True)
class Comparability:
    """Which recorded decisions of one thruster a replay from fresh nodes reproduces.

    Attributes
    ----------
    first_ns : int or None
        Stamp of the first comparable decision (the replay's first); None when none is.
    labels : bool
        Whether labels are compared too (the recording holds the decision layer's start).
    labels_until_ns : int or None
        A ``stale`` diagnosis restarted the live decision layer here: labels are compared
        only before it.
    not_comparable : dict of str to int
        Recorded decisions not comparable, by reason (``NOT_COMPARABLE_REASONS``).
    """

    first_ns: int | None
    labels: bool
    labels_until_ns: int | None
    not_comparable: dict[str, int]

    def compares_label(self, stamp_ns: int) -> bool:
        """Whether the label of the decision at ``stamp_ns`` is compared."""
        return self.labels and (self.labels_until_ns is None or stamp_ns < self.labels_until_ns)


@dataclass(frozen=True)
class ChainTiming:
    """How a decision depends on the past, from the models' cards and the hop.

    Attributes
    ----------
    period_s : float
        The nominal model's sample time, s.
    warmup_samples : int
        Samples the nominal model is fed before its first prediction (its largest lookback).
    parallel : bool
        The model feeds back its own outputs (parallel mode), not the measured ones.
    window_samples : int
        Samples per classifier window.
    hop_samples : int
        Samples between two decisions.
    """

    period_s: float
    warmup_samples: int
    parallel: bool
    window_samples: int
    hop_samples: int


def chain_timing(models: Path, hop_s: float = 1.0) -> ChainTiming:
    """The ``ChainTiming`` of the exported pair in ``models`` (``nominal/``, ``classifier/``)
    with decisions every ``hop_s`` s (a window of 4 samples without a classifier)."""
    card = read_nominal_card(models / "nominal")
    window = 4
    if (models / "classifier" / CARD_FILE).is_file():
        window = read_classifier_card(models / "classifier").lookbacks["window_samples"]
    return ChainTiming(
        period_s=card.sample_time_s,
        warmup_samples=max(card.lookbacks["input"], card.lookbacks["output"]),
        parallel=card.mode == "parallel",
        window_samples=window,
        hop_samples=max(1, round(hop_s / card.sample_time_s)),
    )


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
    recorded : tuple of WindowDecision
        Diagnoses recorded live, in stamp order.
    truth : tuple of (float, str)
        Ground-truth label segments (start s, class) from simulation metadata; empty if none.
    used_residuals : bool
        The samples are those of the recorded residuals (the live model's), not a decimation.
    residuals : tuple of (int, int)
        The recorded residuals: (header stamp ns, flags), in stamp order.
    origin_ns : int
        The recording's ``time_origin_ns`` (0 for a live one).
    comparable : Comparability or None
        What a replay of ``stamps_ns`` reproduces (``align_bag``); None before alignment or
        without recorded decisions.
    """

    thruster_id: str
    stamps_ns: tuple[int, ...]
    raw: tuple[bytes, ...]
    recorded: tuple[WindowDecision, ...]
    truth: tuple[tuple[float, str], ...]
    used_residuals: bool = False
    residuals: tuple[tuple[int, int], ...] = ()
    origin_ns: int = 0
    comparable: Comparability | None = None

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
    recorded: dict[str, list[WindowDecision]] = {}
    used: dict[str, dict[int, int]] = {}
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
            decision = diagnosis_of(ns, decoded) if match["kind"] == "fdd/diagnosis" else None
            flags = int(decoded.flags) if match["kind"] == "fdd/residual" else 0
        except DECODE_ERRORS:
            skipped[channel.topic] = skipped.get(channel.topic, 0) + 1
            continue
        tid = match["id"]
        if match["kind"] == "esc/telemetry":
            telemetry.setdefault(tid, []).append((ns, data))
        elif match["kind"] == "fdd/residual":
            used.setdefault(tid, {})[ns] = flags
        elif decision is not None:
            recorded.setdefault(tid, []).append(decision)
    problems += [
        f"{topic}: {n} message(s) of another type or not decodable, skipped"
        for topic, n in skipped.items()
    ]
    warn_if_damaged(contents, tuple(problems))
    if not telemetry:
        raise BadInputError(f"{path}: no readable /thruster/<id>/esc/telemetry messages to replay")
    try:
        origin_ns = int(meta.get(ORIGIN_KEY, "0") or 0)
    except ValueError:
        raise BadInputError(f"{path}: {ORIGIN_KEY} metadata is not an integer") from None
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
                recorded=tuple(sorted(recorded.get(tid, []), key=lambda d: d.stamp_ns)),
                truth=_segments(path, truth.get(tid, "")),
                used_residuals=tid in used,
                residuals=tuple(sorted(used.get(tid, {}).items())),
                origin_ns=origin_ns,
            )
        )
    return tuple(bags)


def diagnosis_of(stamp_ns: int, msg: Any) -> WindowDecision:
    """The ``WindowDecision`` of a decoded ``Diagnosis`` (a ROS or a bag-decoded message)."""
    return WindowDecision(
        stamp_ns=stamp_ns,
        label=str(msg.label),
        probabilities=tuple(float(p) for p in msg.probabilities),
        covered=bool(msg.covered),
        reason=str(msg.reason),
    )


def merge_bags(parts: list[tuple[ThrusterBag, ...]]) -> tuple[ThrusterBag, ...]:
    """One ``ThrusterBag`` per thruster from the files of a split recording, in file order (a
    sample, residual or decision a later file repeats is kept once)."""
    merged: dict[str, ThrusterBag] = {}
    for bags in parts:
        for bag in bags:
            old = merged.get(bag.thruster_id)
            if old is None:
                merged[bag.thruster_id] = bag
                continue
            keep = [i for i, ns in enumerate(bag.stamps_ns) if ns > old.stamps_ns[-1]]
            residuals = dict(old.residuals) | dict(bag.residuals)
            recorded = {(d.stamp_ns, d.reason): d for d in (*old.recorded, *bag.recorded)}
            merged[bag.thruster_id] = replace(
                old,
                stamps_ns=old.stamps_ns + tuple(bag.stamps_ns[i] for i in keep),
                raw=old.raw + tuple(bag.raw[i] for i in keep),
                recorded=tuple(sorted(recorded.values(), key=lambda d: d.stamp_ns)),
                truth=old.truth or bag.truth,
                residuals=tuple(sorted(residuals.items())),
            )
    return tuple(merged[tid] for tid in sorted(merged))


def load_recording(path: Path, timing: ChainTiming) -> tuple[ThrusterBag, ...]:
    """Every thruster of a recording (a bag folder, split files merged, or one MCAP file),
    aligned for a replay (``align_bag``); an empty or damaged split is skipped with a warning.

    Raises
    ------
    BadInputError
        As ``load_bag``.
    """
    if is_bag(path):
        parts = read_splits(path, lambda file: load_bag(file, timing.period_s))
    else:
        parts = [load_bag(path, timing.period_s)]
    return tuple(align_bag(bag, timing) for bag in merge_bags(parts))


def _first_decision(
    stamps_ns: list[int], valid: list[bool], span: tuple[int, int], ready: int, timing: ChainTiming
) -> int | None:
    """Index of the first decision of a fresh classifier fed the samples of ``span`` (start,
    end exclusive) whose residuals are valid from ``ready`` on as ``valid`` says, by the
    classifier's own window code; None when there is none."""
    windows = WindowFeaturizer(timing.window_samples, timing.hop_samples, timing.period_s)
    values = (0.0, 15.0, 0.0, 0.0, 0.0, 0.0)  # the window's values do not move its grid
    for k in range(*span):
        if windows.push(stamps_ns[k] * 1e-9, values, valid[k] and k >= ready) is not None:
            return k
    return None


def _restarts(flags: list[int], k: int, warmup_samples: int) -> bool:
    """Whether the live nominal model started from an empty lookback at residual ``k``.

    It did when ``k`` is a warm-up residual after a usable or refused one, the first
    STATE_RESET of a warm-up (a reset during the model's first warm-up), or when exactly
    ``warmup_samples`` warm-up residuals from ``k`` on precede a prediction: every fed sample
    gives one residual, so the lookback was empty just before ``k``. The last rule places a
    reset within a warm-up that follows another (every residual of it is flagged
    STATE_RESET) and tells a recording's first residual from one in the middle of a warm-up.
    """
    if not flags[k] & WARMING_UP:
        return False
    if k > 0 and (not flags[k - 1] & WARMING_UP or flags[k] & ~flags[k - 1] & STATE_RESET):
        return True
    run = flags[k : k + warmup_samples + 1]
    return (
        len(run) == warmup_samples + 1
        and all(f & WARMING_UP for f in run[:-1])
        and not run[-1] & (WARMING_UP | INPUT_INVALID)
    )


def align_bag(bag: ThrusterBag, timing: ChainTiming) -> ThrusterBag:
    """``bag`` with the samples to replay cut to those that make the replay's decisions the
    live ones, and what is comparable (``Comparability``; module docstring).

    The replay starts at the first sample from which a fresh nominal model reproduces the live
    one's residuals and a fresh classifier's first window is a recorded decision's (its grid
    then is the live grid); it stops before the first sample the live model used (a recorded
    residual) whose telemetry the recording lacks. A bag without recorded residuals or
    decisions (a simulated recording) is returned unchanged.
    """
    index = {ns: k for k, (ns, _) in enumerate(bag.residuals)}
    decided = [d for d in bag.recorded if d.stamp_ns in index]
    if not bag.used_residuals or not decided:
        return bag
    stamps = [ns for ns, _ in bag.residuals]
    flags = [f for _, f in bag.residuals]
    held = set(bag.stamps_ns)
    begin = index[bag.stamps_ns[0]]
    end = next((k for k in range(begin, len(stamps)) if stamps[k] not in held), len(stamps))
    live_valid = [not f & (WARMING_UP | INPUT_INVALID) for f in flags]
    decided_ns = {d.stamp_ns for d in decided}
    start = first = None
    for a in range(begin, end):
        if timing.parallel and not _restarts(flags, a, timing.warmup_samples):
            continue
        # A fresh model predicts from warmup_samples on; from there on (and from a restart
        # in parallel mode) its residuals and their flags are the live ones.
        ready = a if timing.parallel else a + timing.warmup_samples
        f = _first_decision(stamps, live_valid, (a, end), ready, timing)
        if f is None or stamps[f] > decided[-1].stamp_ns:
            break
        if stamps[f] in decided_ns:
            start, first = a, stamps[f]
            break
    last_ns = stamps[end - 1]
    counts = {
        BEFORE_RECORDING: sum(1 for d in decided if first is None or d.stamp_ns < first),
        MISSING_SAMPLE: sum(1 for d in decided if first is not None and d.stamp_ns > last_ns),
    }
    # The decision layer started at the model's first residual, its first warm-up: flagged
    # WARMING_UP without STATE_RESET (every warm-up after a reset carries STATE_RESET), and
    # its first residual, not one in the middle of that warm-up.
    labels = (
        start == 0
        and flags[0] & (WARMING_UP | STATE_RESET) == WARMING_UP
        and _restarts(flags, 0, timing.warmup_samples)
    )
    until = next(
        (d.stamp_ns for d in bag.recorded if d.reason == "stale" and first is not None
         and d.stamp_ns > first),
        None,
    )  # fmt: skip
    comparable = Comparability(first, labels, until, {k: n for k, n in counts.items() if n})
    keep = [
        i
        for i, ns in enumerate(bag.stamps_ns)
        if start is not None and stamps[start] <= ns <= last_ns
    ]
    return replace(
        bag,
        stamps_ns=tuple(bag.stamps_ns[i] for i in keep),
        raw=tuple(bag.raw[i] for i in keep),
        comparable=comparable,
    )


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
        The replay's collapsed label sequence (``unknown`` dropped), over the compared
        decisions when recorded ones are the expectation.
    expected_sequence : list of str or None
        The recorded (or ground-truth) collapsed sequence, over the same decisions; None when
        the bag has neither. Recorded sequences must be equal only over the decisions whose
        labels are compared.
    source : str
        ``recorded``, ``truth`` or ``none``.
    agreement : float or None
        Fraction of compared decisions that agree. Recorded: the live and the replayed decision
        of the same window (the same header stamp, the window's last sample) from the first
        comparable one to the last both could make; they agree when both exist and decided the
        window alike (``WindowDecision.same_window``) and, where labels are compared, published
        the same label; a replayed decision of a window the live run did not decide, or the
        reverse, disagrees. Ground truth: the class at its time, decisions within ``settle_s``
        after a label change and ``unknown`` ones not counted. None when nothing is compared.
    passed : bool
        Agreement at least the threshold and, where labels are compared, the sequences equal
        (True when nothing is expected; False when decisions are recorded but none is
        comparable).
    compared : int
        Decisions compared.
    labels_compared : bool
        Whether labels were part of the comparison.
    not_comparable : dict of str to int
        Recorded decisions not compared, by reason (``NOT_COMPARABLE_REASONS``).
    after_recorded : int
        Replayed decisions after the last recorded one (the recording stopped first).
    """

    thruster_id: str
    decisions: int
    sequence: list[str]
    expected_sequence: list[str] | None
    source: str
    agreement: float | None
    passed: bool
    compared: int = 0
    labels_compared: bool = False
    not_comparable: dict[str, int] | None = None
    after_recorded: int = 0


def _check_recorded(
    bag: ThrusterBag, comparable: Comparability, got: list[WindowDecision], min_agreement: float
) -> ReplayCheck:
    """``check_replay`` against the decisions recorded live."""
    index = {ns for ns, _ in bag.residuals}
    live = {d.stamp_ns: d for d in bag.recorded if d.stamp_ns in index}
    first = comparable.first_ns
    last_live = max(live, default=0)
    last_sample = bag.stamps_ns[-1] if bag.stamps_ns else 0
    replayed = {d.stamp_ns: d for d in got if first is not None and first <= d.stamp_ns}
    tail = sum(1 for ns in replayed if ns > last_live)
    stamps = sorted(
        {ns for ns in replayed if ns <= last_live}
        | {ns for ns in live if first is not None and first <= ns <= last_sample}
    )

    def agree(ns: int) -> bool:
        a, b = live.get(ns), replayed.get(ns)
        if a is None or b is None or not a.same_window(b):
            return False
        return a.label == b.label or not comparable.compares_label(ns)

    def labels(decisions: dict[int, WindowDecision], over: list[int]) -> list[str]:
        return collapse([decisions[ns].label for ns in over if ns in decisions
                         and decisions[ns].label != "unknown"])  # fmt: skip

    agreement = sum(1 for ns in stamps if agree(ns)) / len(stamps) if stamps else None
    labelled = [ns for ns in stamps if comparable.compares_label(ns)]
    same_labels = labels(replayed, labelled) == labels(live, labelled)
    passed = agreement is not None and agreement >= min_agreement and same_labels
    return ReplayCheck(
        bag.thruster_id,
        len(got),
        labels(replayed, stamps),
        labels(live, stamps),
        "recorded",
        agreement,
        passed,
        compared=len(stamps),
        labels_compared=bool(labelled),
        not_comparable=dict(comparable.not_comparable),
        after_recorded=tail,
    )


def check_replay(
    bag: ThrusterBag,
    got: list[WindowDecision],
    *,
    min_agreement: float = 0.9,
    settle_s: float = 15.0,
) -> ReplayCheck:
    """Compare replayed diagnoses ``got`` with what ``bag`` (aligned by ``align_bag``)
    expects."""
    if bag.comparable is not None:
        return _check_recorded(bag, bag.comparable, got, min_agreement)
    sequence = collapse([d.label for d in got if d.label != "unknown"])
    if bag.truth:
        changes = [start for start, _ in bag.truth[1:]]
        counted = [
            (bag.truth_at(d.t_s), d.label)
            for d in got
            if not any(0.0 <= d.t_s - c < settle_s for c in changes) and d.label != "unknown"
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


def replayed_samples(trace: Trace, bag: ThrusterBag) -> Trace:
    """The samples of ``trace`` that ``replay`` publishes for ``bag`` (the same thruster,
    aligned by ``align_bag``): those the live nominal model used, from the aligned start, so
    ``diagnose`` and ``replay`` decide on the same windows as each other and as the live run.
    The trace unchanged when the recording has no residuals of its thruster (a simulated
    recording: the decimation is then the same in both).

    Parameters
    ----------
    trace : Trace
        One thruster's telemetry read from the recording (times relative to its
        ``time_origin_ns``).
    bag : ThrusterBag
        The same thruster's part of the recording.
    """
    if not bag.used_residuals:
        return trace
    # Nearest stamp within 10 us: the trace's float times lose the last digits of the ns.
    wanted = np.array([(ns - bag.origin_ns) * 1e-9 for ns in bag.stamps_ns])
    if len(wanted) == 0:
        keep = np.zeros(len(trace), dtype=bool)
    else:
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
