"""No published float is ever non-finite: the core paths behind each published message type,
fed with NaN, inf, huge and random values. ROS-free; the node-level checks are in
test/vehicle/nodes/test_adversarial_nodes.py.

- EscTelemetry: what passes ``check_telemetry`` (the driver publishes nothing else) is finite,
  and so is the command it carries.
- ThrusterCommand: every command signal the player publishes, and the driver's shaping.
- Diagnosis: the decisions of ``DiagnosisStream`` on any residual input.
- DiagnosticArray: every numeric value of the link status, on any counts and periods.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.core.bridge.kiss import KissDecoder, KissFrame
from thruster_fdd.core.bridge.link import (
    LinkWindow,
    assess_link,
    clamp_command,
    command_to_pwm,
    pwm_to_command,
    slew,
)
from thruster_fdd.core.bridge.plausibility import check_telemetry, to_sample
from thruster_fdd.core.bridge.tfdd import FrameDecoder, TelemetryFrame
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.diagnosis.stream import DiagnosisStream
from thruster_fdd_shore.core.sim.signals import make_signal

SOME = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
anything = st.floats(allow_nan=True, allow_infinity=True)
extreme = st.one_of(
    anything,
    st.sampled_from([0.0, -0.0, 1e308, -1e308, 5e-324, 1e154, math.nan, math.inf, -math.inf]),
)


# ----------------------------------------------------------------------------- EscTelemetry


@SOME
@given(
    frame=st.builds(
        TelemetryFrame,
        timestamp_us=st.integers(0, 2**32 - 1),
        pwm_us=st.integers(0, 65535),
        voltage_v=extreme,
        current_a=extreme,
        rpm=extreme,
        temperature_c=extreme,
        status=st.integers(0, 255),
    )
)
def test_telemetry_the_driver_publishes_is_finite(frame: TelemetryFrame) -> None:
    if check_telemetry(frame):
        return  # refused: never published
    sample = to_sample(frame)
    fields = (sample.voltage_v, sample.current_a, sample.rpm, sample.temperature_c)
    assert all(math.isfinite(v) for v in fields)
    assert math.isfinite(pwm_to_command(frame.pwm_us))


@SOME
@given(frame=st.builds(KissFrame, extreme, extreme, extreme, st.integers(0, 65535), extreme))
def test_kiss_telemetry_the_driver_publishes_is_finite(frame: KissFrame) -> None:
    if not check_telemetry(frame):
        assert all(
            math.isfinite(v)
            for v in (frame.voltage_v, frame.current_a, frame.rpm, frame.temperature_c)
        )


@SOME
@given(data=st.binary(max_size=600))
def test_decoded_bytes_are_finite_whatever_arrives(data: bytes) -> None:
    for decoded in FrameDecoder().feed(data):
        message = decoded.message
        if isinstance(message, TelemetryFrame):
            values = (message.voltage_v, message.current_a, message.rpm, message.temperature_c)
            assert all(math.isfinite(v) for v in values)
    for frame in KissDecoder().feed(data):
        assert math.isfinite(frame.voltage_v + frame.current_a + frame.rpm + frame.temperature_c)


# ----------------------------------------------------------------------------- ThrusterCommand


@SOME
@given(
    spec=st.sampled_from(["steps", "sine:0.05", "sine:4.9", "chirp", "multilevel", "mission"]),
    duration=st.floats(0.05, 3600.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_every_command_signal_is_finite_and_in_range(spec: str, duration: float, seed: int) -> None:
    _, command = make_signal(spec, duration, 20.0, seed=seed)
    assert np.all(np.isfinite(command))
    assert np.all(np.abs(command) <= 1.0)


@SOME
@given(previous=st.floats(-1, 1), target=extreme, dt=extreme, rate=extreme)
def test_command_shaping_refuses_non_finite_and_stays_finite(
    previous: float, target: float, dt: float, rate: float
) -> None:
    try:
        target = clamp_command(target)
    except ValueError:
        assert not math.isfinite(target)
        return
    if not (math.isfinite(dt) and math.isfinite(rate)):
        return  # parameters: the driver's are finite numbers
    applied = slew(previous, target, dt, rate)
    assert -1.0 <= applied <= 1.0
    assert 1100 <= command_to_pwm(applied) <= 1900


# ----------------------------------------------------------------------------- Diagnosis


@pytest.fixture(scope="module")
def classifier() -> ClassifierModel:
    return ClassifierModel.load(default_models_dir() / "classifier")


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow,
          HealthCheck.function_scoped_fixture])  # fmt: skip
@given(
    rows=st.lists(st.tuples(extreme, extreme, extreme, extreme, extreme, extreme), min_size=1),
    base=st.tuples(st.floats(-1, 1), st.floats(10, 20), st.floats(-4000, 4000), st.floats(0, 10)),
)
def test_diagnosis_of_any_residuals_is_finite(
    classifier: ClassifierModel,
    rows: list[tuple[float, ...]],
    base: tuple[float, float, float, float],
) -> None:
    """Plausible windows with extreme residuals mixed in (a foreign publisher on fdd/residual
    could send anything finite): every decision's probabilities and confidence are finite."""
    stream = DiagnosisStream(classifier)
    n = 2 * classifier.window_samples  # a seventh of the samples may be skipped as non-finite
    decisions = []
    for i in range(n):
        values = list(rows[i % len(rows)]) if i % 7 == 0 else [*base, 10.0, 0.1]
        decision = stream.push(i * classifier.sample_time_s, *values, True)
        if decision is not None:
            decisions.append(decision)
    assert decisions, "no decision: the test would prove nothing"
    for d in decisions:
        assert all(math.isfinite(p) for p in d.probabilities.values())
        assert math.isfinite(d.confidence)
        assert math.isfinite(d.window_s)
        assert math.isclose(sum(d.probabilities.values()), 1.0, rel_tol=1e-6)


# ----------------------------------------------------------------------------- DiagnosticArray


@SOME
@given(
    period=extreme,
    expected=extreme,
    since=st.one_of(st.none(), extreme),
    counts=st.lists(st.integers(0, 10**9), min_size=12, max_size=12),
)
def test_link_status_values_are_finite_numbers(
    period: float, expected: float, since: float | None, counts: list[int]
) -> None:
    names = (
        *("frames", "crc_errors", "truncated", "garbage_bytes", "lost", "duplicates"),
        *("replayed", "resets", "resyncs", "stuck_low_bytes", "stuck_high_bytes", "rejected"),
    )
    window = LinkWindow(
        period_s=period,
        expected_rate_hz=expected,
        port_open=True,
        since_frame_s=since,
        **dict(zip(names, counts, strict=True)),
    )
    health = assess_link(window)
    for key, value in health.values:
        try:
            number = float(value)
        except ValueError:
            continue
        assert math.isfinite(number), f"{key}={value}"
