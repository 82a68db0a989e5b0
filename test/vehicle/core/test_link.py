"""ESC driver logic: command clamping, slew limit, pwm mapping, link health."""

from __future__ import annotations

import math
import time

import pytest

from thruster_fdd.core.bridge.link import (
    ERROR,
    OK,
    STALE,
    WARN,
    CommandWatchdog,
    LinkWindow,
    assess_link,
    clamp_command,
    command_to_pwm,
    frame_stamps,
    pwm_to_command,
    slew,
)


@pytest.mark.parametrize(("value", "expected"), [(0.3, 0.3), (1.7, 1.0), (-4.0, -1.0)])
def test_clamp(value: float, expected: float) -> None:
    assert clamp_command(value) == expected


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_clamp_refuses_non_finite(value: float) -> None:
    with pytest.raises(ValueError, match="finite"):
        clamp_command(value)


def test_slew_limits_rate_and_reaches_target() -> None:
    value = 0.0
    for _ in range(10):
        value = slew(value, 1.0, 0.05, 4.0)
    assert value == pytest.approx(1.0)
    assert slew(0.0, 1.0, 0.05, 4.0) == pytest.approx(0.2)
    assert slew(0.0, -1.0, 0.05, 4.0) == pytest.approx(-0.2)
    assert slew(0.3, -1.0, 0.05, 0.0) == -1.0


def test_pwm_mapping() -> None:
    assert command_to_pwm(0.0) == 1500
    assert command_to_pwm(-1.0) == 1100
    assert command_to_pwm(2.0) == 1900
    assert pwm_to_command(1600) == pytest.approx(0.25)


def _window(**kw: object) -> LinkWindow:
    base = {"period_s": 1.0, "expected_rate_hz": 50.0, "port_open": True, "frames": 50}
    base["since_frame_s"] = 0.02
    base.update(kw)
    return LinkWindow(**base)  # type: ignore[arg-type]


def test_healthy_link_is_ok() -> None:
    health = assess_link(_window())
    assert health.level == OK
    assert "50.0 Hz" in health.message
    assert ("telemetry_rate_hz", "50.0") in health.values


def test_closed_port_is_error_with_reason() -> None:
    health = assess_link(_window(port_open=False, port_error="/dev/x: no such file"))
    assert health.level == ERROR
    assert "no such file" in health.message


@pytest.mark.parametrize("since", [None, 0.5])
def test_silent_link_is_stale(since: float | None) -> None:
    health = assess_link(_window(frames=0, since_frame_s=since))
    assert health.level == STALE
    assert "50 Hz" in health.message


@pytest.mark.parametrize(
    ("field", "words"),
    [
        ("crc_errors", "CRC errors"),
        ("truncated", "truncated"),
        ("lost", "lost"),
        ("duplicates", "duplicated"),
        ("rejected", "implausible"),
        ("garbage_bytes", "noise"),
    ],
)
def test_each_link_problem_is_a_named_warning(field: str, words: str) -> None:
    health = assess_link(_window(**{field: 3}))
    assert health.level == WARN
    assert words in health.message
    assert "3" in health.message


def test_watchdog_and_bridge_faults_warn() -> None:
    assert "neutral" in assess_link(_window(watchdog_neutral=True)).message
    assert "ADC_FAULT" in assess_link(_window(bridge_faults="ADC_FAULT")).message


def test_frame_stamps_follow_the_bridge_clock_and_increase() -> None:
    assert frame_stamps(10_000_000, []) == []
    assert frame_stamps(10_000_000, [5]) == [10_000_000]
    stamps = frame_stamps(10_000_000, [1_000, 1_020, 1_040])
    assert stamps == [9_960_000, 9_980_000, 10_000_000]
    wrapped = frame_stamps(10_000_000, [(1 << 32) - 10, 10])
    assert wrapped == [9_980_000, 10_000_000]
    no_clock = frame_stamps(10_000_000, [None, None, None], period_ns=5)
    assert no_clock == [9_999_990, 9_999_995, 10_000_000]
    same = frame_stamps(10_000_000, [7, 7])
    assert same[0] < same[1]


def test_a_stale_period_still_names_the_faults_seen_before_the_silence() -> None:
    health = assess_link(
        _window(since_frame_s=0.3, bridge_faults="ADC_FAULT", rejected=1, reject_reason="flag")
    )
    assert health.level == STALE
    assert health.message.startswith("no telemetry for 0.3 s")
    assert "bridge reports ADC_FAULT" in health.message
    assert "1 implausible samples refused (flag)" in health.message
    assert assess_link(_window(frames=0, since_frame_s=0.3)).message == (
        "no telemetry for 0.3 s (expected 50 Hz)"
    )


class _Clocks:
    """A host clock and a monotonic clock the test moves by hand, ns."""

    def __init__(self) -> None:
        self.wall_ns = 1_800_000_000 * 10**9
        self.mono_ns = 5 * 10**9

    def advance(self, seconds: float, wall_step_s: float = 0.0) -> None:
        self.mono_ns += round(seconds * 1e9)
        self.wall_ns += round((seconds + wall_step_s) * 1e9)


def test_watchdog_neutral_after_timeout_when_host_clock_steps_back(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    clocks = _Clocks()
    monkeypatch.setattr(time, "time_ns", lambda: clocks.wall_ns)
    monkeypatch.setattr(time, "monotonic_ns", lambda: clocks.mono_ns)
    watchdog = CommandWatchdog(0.5, 0.0)  # the driver's default clock
    watchdog.restart()
    watchdog.command(0.8)
    clocks.advance(0.05)
    assert command_to_pwm(watchdog.step()) == 1820
    assert not watchdog.neutral
    # The host clock is stepped back 60 s while no command arrives.
    clocks.advance(0.3, wall_step_s=-60.0)
    assert command_to_pwm(watchdog.step()) == 1820
    clocks.advance(0.3)
    assert watchdog.step() == 0.0
    assert watchdog.neutral


def test_watchdog_slews_on_monotonic_intervals_and_refuses_non_finite() -> None:
    clocks = _Clocks()
    watchdog = CommandWatchdog(0.5, 4.0, clock_ns=lambda: clocks.mono_ns)
    watchdog.command(1.0)
    clocks.advance(0.05)
    assert watchdog.step() == pytest.approx(0.2)
    with pytest.raises(ValueError, match="finite"):
        watchdog.command(math.nan)
    assert watchdog.target == 1.0
    watchdog.stop()
    assert watchdog.applied == watchdog.target == 0.0
