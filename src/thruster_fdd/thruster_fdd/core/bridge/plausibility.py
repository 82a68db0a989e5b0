"""Physical plausibility of telemetry from either wire format: what the driver refuses."""

from __future__ import annotations

import math
from dataclasses import dataclass

from thruster_fdd.core.bridge.kiss import KissFrame
from thruster_fdd.core.bridge.tfdd import StatusFlag, TelemetryFrame


@dataclass(frozen=True)
class TelemetrySample:
    """Telemetry fields common to both protocols; None where the protocol lacks the field.

    Attributes
    ----------
    voltage_v, current_a, rpm, temperature_c : float or None
        V, A (signed in tfdd, unsigned in KISS), rpm (signed in tfdd, unsigned in KISS), °C.
    pwm_us : int or None
        Pulse applied by the bridge in µs (tfdd only).
    timestamp_us : int or None
        Microcontroller clock in µs (tfdd only).
    status : int or None
        ``StatusFlag`` bits (tfdd only).
    consumption_mah : int or None
        Charge drawn since power-up in mAh (KISS only).
    """

    voltage_v: float | None
    current_a: float | None
    rpm: float | None
    temperature_c: float | None
    pwm_us: int | None = None
    timestamp_us: int | None = None
    status: int | None = None
    consumption_mah: int | None = None


def to_sample(frame: TelemetryFrame | KissFrame) -> TelemetrySample:
    """Map either protocol's telemetry onto the common physical fields."""
    if isinstance(frame, KissFrame):
        return TelemetrySample(
            frame.voltage_v,
            frame.current_a,
            frame.rpm,
            frame.temperature_c,
            consumption_mah=frame.consumption_mah,
        )
    return TelemetrySample(
        frame.voltage_v,
        frame.current_a,
        frame.rpm,
        frame.temperature_c,
        pwm_us=frame.pwm_us,
        timestamp_us=frame.timestamp_us,
        status=frame.status,
    )


PLAUSIBLE_LIMITS: dict[str, tuple[float, float]] = {
    "voltage_v": (0.0, 60.0),
    "current_a": (-60.0, 60.0),
    "rpm": (-10_000.0, 10_000.0),
    "temperature_c": (-20.0, 125.0),
    "pwm_us": (900.0, 2100.0),
}
"""Inclusive (low, high) bounds, in each field's unit, outside which a sample is implausible
for a T100/T200 on a <= 60 V bus (about 3x the T200's 20 V / 35 A / 5000 rpm envelope)."""


_FAULT_FLAGS = (StatusFlag.ADC_FAULT, StatusFlag.RPM_FAULT)


def check_telemetry(frame: TelemetryFrame | KissFrame | TelemetrySample) -> tuple[str, ...]:
    """List why a telemetry sample is physically implausible.

    Parameters
    ----------
    frame : TelemetryFrame, KissFrame or TelemetrySample
        The sample; fields that are None are not checked.

    Returns
    -------
    tuple of str
        One human-readable problem per offending field or fault flag; empty when plausible.
    """
    sample = frame if isinstance(frame, TelemetrySample) else to_sample(frame)
    problems: list[str] = []
    for name, (lo, hi) in PLAUSIBLE_LIMITS.items():
        value = getattr(sample, name)
        if value is None:
            continue
        if not math.isfinite(value):
            problems.append(f"{name} is {value}")
        elif not lo <= value <= hi:
            problems.append(f"{name}={value:g} outside {lo:g}..{hi:g}")
    if sample.status is not None:
        problems.extend(
            f"status flag {flag.name} set" for flag in _FAULT_FLAGS if sample.status & flag
        )
    return tuple(problems)
