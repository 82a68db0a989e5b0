"""How replayed diagnoses are judged against recorded ones (traces.replay_check)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from thruster_fdd.core.nominal.residuals import INPUT_INVALID, OK, STATE_RESET, ResidualStream
from thruster_fdd_shore.core.traces.replay_check import (
    BEFORE_RECORDING,
    MISSING_SAMPLE,
    ChainTiming,
    Comparability,
    ThrusterBag,
    WindowDecision,
    align_bag,
    check_replay,
)

NOMINAL = (0.9, 0.02, 0.02, 0.02, 0.02, 0.02)
BLADES = (0.02, 0.02, 0.02, 0.02, 0.9, 0.02)
# A small chain: 3 samples of model history, windows of 8 samples, a decision every 2.
TIMING = ChainTiming(
    period_s=0.1, warmup_samples=3, parallel=False, window_samples=8, hop_samples=2
)
T0_NS = 1_000_000_000_000


def _decision(i: int, label: str, probabilities: tuple[float, ...] = NOMINAL) -> WindowDecision:
    return WindowDecision(T0_NS + i * 1_000_000_000, label, probabilities)


def _bag(recorded: list[WindowDecision], labels: bool = True) -> ThrusterBag:
    """A bag whose recorded decisions are all comparable (labels too, unless ``labels``)."""
    residuals = tuple((d.stamp_ns, OK) for d in recorded)
    comparable = Comparability(recorded[0].stamp_ns, labels, None, {})
    stamps = tuple(ns for ns, _ in residuals)
    return ThrusterBag("t0", stamps, (), tuple(recorded), (), True, residuals, 0, comparable)


def _live(n: int = 40, change_at: int = 20) -> list[WindowDecision]:
    return [
        _decision(i, "nominal_15v") if i < change_at else _decision(i, "broken_blade_2", BLADES)
        for i in range(n)
    ]


def test_identical_decisions_agree_fully() -> None:
    live = _live()
    result = check_replay(_bag(live), live)
    assert result.passed
    assert result.agreement == 1.0
    assert result.compared == 40
    assert result.sequence == ["nominal_15v", "broken_blade_2"]


def test_windows_shifted_against_the_live_ones_disagree() -> None:
    # Decisions 0.1 s later are on other windows, however alike their labels.
    live = _live()
    replayed = [replace(d, stamp_ns=d.stamp_ns + 100_000_000) for d in live]
    result = check_replay(_bag(live), replayed)
    assert result.agreement == 0.0
    assert not result.passed


def test_unknown_is_compared_as_a_label() -> None:
    live = [_decision(i, "unknown" if i < 10 else "nominal_15v") for i in range(40)]
    replayed = [replace(d, label="nominal_15v") for d in live]
    result = check_replay(_bag(live), replayed, min_agreement=0.9)
    assert result.agreement == 30 / 40
    assert not result.passed


def test_a_late_change_lowers_the_agreement_and_fails() -> None:
    live = _live()
    replayed = [replace(d, label=b.label) for d, b in zip(live, _live(change_at=26), strict=True)]
    result = check_replay(_bag(live), replayed, min_agreement=0.9)
    assert result.agreement == 34 / 40
    assert not result.passed


def test_a_different_sequence_fails_even_with_high_agreement() -> None:
    live = _live()
    replayed = [*live[:-1], replace(live[-1], label="biofouling")]
    result = check_replay(_bag(live), replayed, min_agreement=0.9)
    assert result.agreement > 0.9
    assert not result.passed


def test_other_probabilities_of_a_window_disagree_with_the_same_label() -> None:
    live = _live()
    replayed = [*live[:5], replace(live[5], probabilities=(0.8, *NOMINAL[1:-1], 0.12)), *live[6:]]
    result = check_replay(_bag(live), replayed, min_agreement=1.0)
    assert result.agreement == 39 / 40
    assert not result.passed


def test_without_comparable_labels_only_the_windows_are_compared() -> None:
    live = _live()
    relabelled = [replace(d, label="unknown", reason="evidence_pending") for d in live]
    assert check_replay(_bag(live, labels=False), relabelled, min_agreement=1.0).passed
    gated = [replace(d, label="unknown", reason="low_excitation") for d in live]
    result = check_replay(_bag(live, labels=False), gated)
    assert result.agreement == 0.0
    assert not result.labels_compared


def test_a_live_decision_the_replay_does_not_make_disagrees() -> None:
    live = _live()
    result = check_replay(_bag(live), live[:10] + live[11:])
    assert result.agreement == 39 / 40


class Lookback3:
    """A nominal model that predicts once it has seen ``TIMING.warmup_samples`` samples."""

    sample_time_s = 0.1

    def __init__(self) -> None:
        self.seen = 0

    def reset(self) -> None:
        self.seen = 0

    def step(
        self, command: float, voltage: float, rpm: float, current: float
    ) -> tuple[float, float] | None:
        self.seen += 1
        return (rpm, current) if self.seen > TIMING.warmup_samples else None


def _stream(
    n: int, resets: tuple[int, ...] = (), refused: tuple[int, ...] = ()
) -> tuple[list[tuple[int, int]], list[int]]:
    """Residuals (stamp ns, flags) of a live chain started at sample 0, its telemetry going
    back in sequence at ``resets`` and refused at ``refused``, and the indices it decided at
    (``TIMING``). The flags are those ``ResidualStream`` gives."""
    stream = ResidualStream(Lookback3())
    residuals, decided = [], []
    count = since = 0
    for k in range(n):
        out = stream.push(
            k * TIMING.period_s,
            0.3,
            15.0,
            1000.0,
            math.nan if k in refused else 2.0,
            sequence=-k if k in resets else k,
        )
        assert out is not None
        residuals.append((T0_NS + k * 100_000_000, out.flags))
        if not out.valid:
            if out.flags & (STATE_RESET | INPUT_INVALID):
                count = 0
            continue
        count += 1
        since += 1
        if count == TIMING.window_samples or (
            count > TIMING.window_samples and since >= TIMING.hop_samples
        ):
            decided.append(k)
            since = 0
    return residuals, decided


def _recorded_bag(
    n: int,
    held: range,
    resets: tuple[int, ...] = (),
    refused: tuple[int, ...] = (),
    residuals_from: int = 0,
) -> ThrusterBag:
    """A live recording of ``_stream`` holding the telemetry of ``held`` and the residuals
    and decisions from ``residuals_from`` on (0: the residuals' transient-local history
    reaches back to the chain's start)."""
    residuals, decided = _stream(n, resets, refused)
    stamps = tuple(residuals[k][0] for k in held)
    return ThrusterBag(
        "t0",
        stamps,
        tuple(b"" for _ in stamps),
        tuple(
            WindowDecision(residuals[k][0], "nominal_15v", NOMINAL)
            for k in decided
            if k >= residuals_from
        ),
        (),
        True,
        tuple(residuals[residuals_from:]),
    )


def test_a_bag_from_the_chain_start_compares_every_decision_and_the_labels() -> None:
    bag = align_bag(_recorded_bag(60, range(60)), TIMING)
    assert bag.comparable == Comparability(bag.recorded[0].stamp_ns, True, None, {})
    assert len(bag.stamps_ns) == 60


def test_a_bag_begun_mid_stream_starts_where_fresh_nodes_meet_the_live_windows() -> None:
    # Live decisions at samples 10, 12, 14, ...; telemetry from sample 5. A replay from 5
    # would decide first at 5 + 3 + 7 = 15, between two live windows; from 6 it decides at 16.
    bag = align_bag(_recorded_bag(60, range(5, 60)), TIMING)
    first = T0_NS + 16 * 100_000_000
    assert bag.comparable == Comparability(first, False, None, {BEFORE_RECORDING: 3})
    assert bag.stamps_ns[0] == T0_NS + 6 * 100_000_000
    replayed = [d for d in bag.recorded if d.stamp_ns >= first]
    result = check_replay(bag, replayed, min_agreement=1.0)
    assert result.passed
    assert (result.compared, result.not_comparable) == (len(replayed), {BEFORE_RECORDING: 3})


def test_a_sample_missing_from_the_telemetry_ends_what_is_comparable() -> None:
    held = [k for k in range(60) if k != 40]
    full = _recorded_bag(60, range(60))
    bag = align_bag(replace(full, stamps_ns=tuple(full.residuals[k][0] for k in held)), TIMING)
    assert bag.stamps_ns[-1] == T0_NS + 39 * 100_000_000
    after = sum(1 for d in full.recorded if d.stamp_ns > bag.stamps_ns[-1])
    assert bag.comparable is not None
    assert bag.comparable.not_comparable == {MISSING_SAMPLE: after}


def test_a_stale_diagnosis_ends_the_label_comparison() -> None:
    full = _recorded_bag(60, range(60))
    stale = WindowDecision(T0_NS + 30 * 100_000_000 + 1, "unknown", reason="stale")
    bag = align_bag(replace(full, recorded=(*full.recorded, stale)), TIMING)
    assert bag.comparable is not None
    assert bag.comparable.compares_label(T0_NS + 30 * 100_000_000)
    assert not bag.comparable.compares_label(T0_NS + 32 * 100_000_000)


@pytest.mark.parametrize("reset", [None, 30])
def test_a_parallel_model_is_reproduced_only_from_a_reset(reset: int | None) -> None:
    # Its outputs feed back: a mid-stream bag is comparable only after the live model restarts.
    timing = replace(TIMING, parallel=True)
    resets = () if reset is None else (reset,)
    bag = align_bag(_recorded_bag(60, range(5, 60), resets), timing)
    assert bag.comparable is not None
    if reset is None:
        assert bag.comparable.first_ns is None
        assert bag.stamps_ns == ()
    else:
        assert bag.stamps_ns[0] == T0_NS + reset * 100_000_000
        assert bag.comparable.first_ns == T0_NS + (reset + 3 + 7) * 100_000_000


def test_a_bag_begun_at_the_warm_up_after_a_refused_sample_compares_no_labels() -> None:
    # The live decision layer has run since sample 0; the model reset at the refused sample 20
    # and warms up again from 21, where the recording begins.
    bag = align_bag(_recorded_bag(60, range(21, 60), refused=(20,), residuals_from=21), TIMING)
    assert bag.comparable is not None
    assert bag.comparable.first_ns is not None
    assert not bag.comparable.labels


def test_a_bag_begun_inside_the_first_warm_up_compares_no_labels() -> None:
    # The live chain decided at sample 10 on windows since sample 0; from sample 2 a fresh
    # chain meets the live windows at 12, but the evidence of the decision at 10 is missing.
    bag = align_bag(_recorded_bag(60, range(2, 60), residuals_from=2), TIMING)
    assert bag.comparable is not None
    assert bag.comparable.first_ns == T0_NS + 12 * 100_000_000
    assert not bag.comparable.labels


def test_a_bag_begun_at_the_chain_start_without_history_compares_the_labels() -> None:
    bag = align_bag(_recorded_bag(60, range(60), refused=(20,), residuals_from=0), TIMING)
    assert bag.comparable is not None
    assert bag.comparable.labels


def test_a_parallel_model_is_not_reproduced_from_inside_a_warm_up_after_a_reset() -> None:
    # Its lookback at sample 31 holds sample 30; a fresh model from 31 is not the live one.
    timing = replace(TIMING, parallel=True)
    bag = align_bag(_recorded_bag(60, range(31, 60), resets=(30,), residuals_from=31), timing)
    assert bag.comparable is not None
    assert bag.comparable.first_ns is None
