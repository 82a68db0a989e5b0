"""How replayed diagnoses are judged against recorded ones (traces.replay_check)."""

from __future__ import annotations

from thruster_fdd_shore.core.traces.replay_check import ThrusterBag, check_replay


def _bag(recorded: list[tuple[float, str]]) -> ThrusterBag:
    return ThrusterBag("t0", (), (), tuple(recorded), ())


def _live(n: int = 40, change_at: int = 20, t0: float = 100.0) -> list[tuple[float, str]]:
    return [(t0 + i, "nominal_15v" if i < change_at else "broken_blade_2") for i in range(n)]


def test_identical_stamps_and_labels_agree_fully() -> None:
    live = _live()
    result = check_replay(_bag(live), live)
    assert result.passed
    assert result.agreement == 1.0
    assert result.sequence == ["nominal_15v", "broken_blade_2"]


def test_windows_shifted_against_the_live_ones_disagree() -> None:
    # A replay that lost the first live samples decides on other windows: 0.1 s later is not
    # the same decision, however alike the labels (issue 50, item 1).
    live = _live()
    replayed = [(t + 0.1, label) for t, label in live]
    result = check_replay(_bag(live), replayed)
    assert result.agreement == 0.0
    assert not result.passed


def test_unknown_is_compared_as_a_label() -> None:
    live = [(100.0 + i, "unknown" if i < 10 else "nominal_15v") for i in range(40)]
    replayed = [(t, "nominal_15v") for t, _ in live]
    result = check_replay(_bag(live), replayed, min_agreement=0.9)
    assert result.agreement == 30 / 40
    assert not result.passed


def test_a_late_change_lowers_the_agreement_and_fails() -> None:
    live = _live()
    replayed = _live(change_at=26)
    result = check_replay(_bag(live), replayed, min_agreement=0.9)
    assert result.agreement == 34 / 40
    assert not result.passed


def test_decisions_far_from_any_recorded_one_are_not_counted() -> None:
    live = _live()
    replayed = [(t + 500.0, label) for t, label in live]
    result = check_replay(_bag(live), replayed)
    assert result.agreement == 0.0
    assert not result.passed


def test_a_different_sequence_fails_even_with_high_agreement() -> None:
    live = _live()
    replayed = [*live[:-1], (live[-1][0], "biofouling")]
    result = check_replay(_bag(live), replayed, min_agreement=0.9)
    assert result.agreement > 0.9
    assert not result.passed
