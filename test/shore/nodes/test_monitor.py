"""The live table's monitor: its rows come from the ``/diagnostics`` summaries of the drivers and
nominal models, fed here straight to its callbacks; it subscribes to no 50 Hz topic."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from diagnostic_msgs.msg import DiagnosticArray

    from thruster_fdd_shore.nodes.monitor import Monitor

pytestmark = pytest.mark.ros

ESC_T0 = {
    "telemetry_rate_hz": "49.5",
    "command": "0.30",
    "pwm_us": "1620",
    "voltage_v": "15.02",
    "current_a": "1.25",
    "rpm": "1480",
    "temperature_c": "31.5",
}


@pytest.fixture
def monitor() -> Iterator[Monitor]:
    import rclpy

    from thruster_fdd_shore.nodes.monitor import Monitor

    rclpy.init()  # the monitor, as up makes it, lives in the default context
    node = Monitor(["t0", "t1"], "monitor_under_test")
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def _array(*statuses: tuple[int, str, str, dict[str, str]]) -> DiagnosticArray:
    """A ``DiagnosticArray`` of ``(level, name, message, values)``."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    return DiagnosticArray(
        status=[
            DiagnosticStatus(
                level=bytes([level]),
                name=name,
                message=message,
                values=[KeyValue(key=k, value=v) for k, v in values.items()],
            )
            for level, name, message, values in statuses
        ]
    )


def test_subscribes_to_no_50_hz_topic(monitor: Monitor) -> None:
    topics = {sub.topic_name for sub in monitor.subscriptions}
    assert topics == {"/diagnostics", "/thruster/t0/fdd/diagnosis", "/thruster/t1/fdd/diagnosis"}


def test_table_renders_the_status_summaries(monitor: Monitor) -> None:
    from thruster_fdd_msgs.msg import Diagnosis

    inactive = {k: "-" for k in ESC_T0} | {"telemetry_rate_hz": "0.0"}
    monitor._on_diagnostics(
        _array(
            (0, "thruster_fdd: esc t0", "telemetry 49.5 Hz", ESC_T0),
            (0, "thruster_fdd: nominal_model t0", "residuals 10.0 Hz", {
                "rms_residual_rpm": "12.3", "rms_residual_a": "0.045"
            }),
            (1, "thruster_fdd: esc t1", "inactive (commands not forwarded)", inactive),
            (0, "thruster_fdd: recorder", "recording", {"matched": "/a,/b", "bag": "/bags/up_1"}),
        )
    )  # fmt: skip
    monitor._on_diagnosis("t0", Diagnosis(label="nominal_15v", confidence=0.97))

    header, t0, t1 = monitor.table().splitlines()
    assert header.split()[:3] == ["id", "rate", "Hz"]
    assert t0.split() == [
        "t0", "49.5", "0.30", "1620", "15.02", "1.25", "1480", "31.5", "12.3", "0.045",
        "nominal_15v", "(0.97)", "OK:", "telemetry", "49.5", "Hz",
    ]  # fmt: skip
    # Each value right-aligned under its column heading.
    for heading, value in (("rate Hz", "49.5"), ("rpm", "1480"), ("res A", "0.045")):
        assert header.index(heading) + len(heading) == t0.index(f" {value} ") + 1 + len(value)
    assert "(no telemetry yet)" in t1
    assert t1.endswith("WARN: inactive (commands not forwarded)")
    assert monitor.recorder_matched == {"/a", "/b"}
    assert monitor.recorder_bag == "/bags/up_1"


def test_a_row_without_a_recent_driver_status_is_marked_stale(monitor: Monitor) -> None:
    from thruster_fdd_shore.nodes.monitor import STATUS_STALE_S

    monitor._on_diagnostics(_array((0, "thruster_fdd: esc t0", "telemetry 49.5 Hz", ESC_T0)))
    assert "STALE" not in monitor.table()
    monitor.rows["t0"].esc_seen_s -= STATUS_STALE_S + 1.0
    (t0,) = [line for line in monitor.table().splitlines() if line.startswith("t0")]
    assert "STALE: no driver status for 6 s; OK: telemetry 49.5 Hz" in t0
    assert " (no telemetry yet)" in monitor.table().splitlines()[2], "t1 reported nothing"
