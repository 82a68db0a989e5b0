"""ResidualStream: decimation to the model period, gaps, invalid input, flags, never NaN."""

from __future__ import annotations

import math

import pytest

from thruster_fdd.core.nominal.residuals import (
    INPUT_INVALID,
    OK,
    STATE_RESET,
    WARMING_UP,
    ResidualStream,
    decimate,
)


class Persistence:
    """The naive predictor: this sample's outputs equal the previous sample's (lookback 1)."""

    sample_time_s = 0.1

    def __init__(self) -> None:
        self.previous: tuple[float, float] | None = None
        self.resets = 0

    def reset(self) -> None:
        self.previous = None
        self.resets += 1

    def step(
        self, command: float, voltage: float, rpm: float, current: float
    ) -> tuple[float, float] | None:
        prediction, self.previous = self.previous, (rpm, current)
        return prediction


def _push(stream: ResidualStream, t: float, rpm: float = 1000.0, **kw: float):
    args = {"command": 0.3, "voltage": 15.0, "current": 2.0} | kw
    return stream.push(t, args["command"], args["voltage"], rpm, args["current"])


def test_first_sample_warms_up_then_residuals_are_measured_minus_predicted() -> None:
    stream = ResidualStream(Persistence())
    first = _push(stream, 0.0, rpm=1000.0)
    assert first is not None
    assert first.flags == WARMING_UP
    assert not first.valid
    second = _push(stream, 0.1, rpm=1100.0, current=2.5)
    assert second is not None
    assert second.flags == OK
    assert second.residual_rpm == pytest.approx(100.0)
    assert second.residual_current_a == pytest.approx(0.5)


def test_faster_telemetry_is_decimated_to_the_model_period() -> None:
    stream = ResidualStream(Persistence())
    outputs = [_push(stream, i * 0.02) for i in range(51)]  # 50 Hz for 1 s
    fed = [o for o in outputs if o is not None]
    assert len(fed) == 11
    assert [round(o.t_s, 2) for o in fed] == [round(0.1 * i, 2) for i in range(11)]


def test_time_gap_resets_state_and_flags() -> None:
    model = Persistence()
    stream = ResidualStream(model, max_gap_periods=3.0)
    _push(stream, 0.0)
    _push(stream, 0.1)
    after_gap = _push(stream, 1.0)
    assert after_gap is not None
    assert after_gap.flags == STATE_RESET | WARMING_UP
    assert "gap" in after_gap.reason
    assert stream.resets == 1
    assert _push(stream, 1.1).flags == OK


def test_sequence_going_back_resets() -> None:
    stream = ResidualStream(Persistence())
    stream.push(0.0, 0.1, 15.0, 500.0, 1.0, sequence=10)
    out = stream.push(0.1, 0.1, 15.0, 500.0, 1.0, sequence=3)
    assert out is not None
    assert out.flags & STATE_RESET


@pytest.mark.parametrize(
    ("field", "value", "words"),
    [
        ("rpm", math.nan, "non-finite rpm"),
        ("current", math.inf, "non-finite current"),
        ("voltage", 80.0, "voltage"),
        ("command", 1.5, "command"),
        ("rpm", 25_000.0, "rpm"),
    ],
)
def test_invalid_input_is_flagged_never_nan(field: str, value: float, words: str) -> None:
    model = Persistence()
    stream = ResidualStream(model)
    _push(stream, 0.0)
    _push(stream, 0.1)
    bad = _push(stream, 0.2, **{field: value})
    assert bad is not None
    assert bad.flags == INPUT_INVALID
    assert words in bad.reason
    for number in (bad.measured_rpm, bad.predicted_rpm, bad.residual_rpm, bad.residual_current_a):
        assert math.isfinite(number)
    assert model.previous is None, "the model state must be reset after a bad sample"
    assert _push(stream, 0.3).flags == STATE_RESET | WARMING_UP


class Lookback3(Persistence):
    """Predicts (the previous sample's outputs) once it has seen 3 samples since a reset."""

    def __init__(self) -> None:
        super().__init__()
        self.seen = 0

    def reset(self) -> None:
        super().reset()
        self.seen = 0

    def step(
        self, command: float, voltage: float, rpm: float, current: float
    ) -> tuple[float, float] | None:
        self.seen += 1
        prediction = super().step(command, voltage, rpm, current)
        return prediction if self.seen > 3 else None


@pytest.mark.parametrize(
    ("reset", "bad"),
    [("time gap", {}), ("refused sample", {"rpm": math.nan})],
)
def test_only_the_first_warm_up_lacks_state_reset(reset: str, bad: dict[str, float]) -> None:
    # A consumer that sees WARMING_UP without STATE_RESET knows no residual came before.
    stream = ResidualStream(Lookback3())
    first = [_push(stream, 0.1 * k).flags for k in range(5)]
    assert first == [WARMING_UP] * 3 + [OK] * 2
    if bad:
        assert _push(stream, 0.5, **bad).flags == INPUT_INVALID
    after = [_push(stream, 2.0 + 0.1 * k).flags for k in range(5)]
    assert after == [STATE_RESET | WARMING_UP] * 3 + [OK] * 2, reset


def test_rejects_a_gap_threshold_below_one_period() -> None:
    with pytest.raises(ValueError, match="max_gap_periods"):
        ResidualStream(Persistence(), max_gap_periods=0.5)


def test_decimate_matches_what_the_stream_feeds() -> None:
    import numpy as np

    t = np.cumsum(np.full(200, 0.02) + np.random.default_rng(0).uniform(-0.003, 0.003, 200))
    stream = ResidualStream(Persistence())
    fed = np.array([_push(stream, float(ti)) is not None for ti in t])
    np.testing.assert_array_equal(decimate(t, 0.1), fed)
    assert 35 <= fed.sum() <= 45
