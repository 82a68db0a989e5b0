"""Monitor node: a live table of every thruster's telemetry, residuals, diagnosis and health.

Subscribes, per thruster, to ``esc/telemetry``, ``fdd/residual`` and ``fdd/diagnosis`` under
``/thruster/<id>``, and to ``/diagnostics``; renders one row per thruster: telemetry rate,
command, pwm, voltage, current, rpm, temperature, RMS residuals over the last 2 s, the diagnosis
and the driver's health message. ``thruster-fdd up`` prints it every few seconds.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from thruster_fdd_msgs.msg import Diagnosis, EscTelemetry, Residual

from thruster_fdd.nodes.common import NO_SUB_EVENTS, status_name, subscribe_thrusters

LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
WINDOW_S = 2.0


@dataclass
class _Row:
    """The latest state of one thruster (mutable: updated by callbacks)."""

    stamps: deque[float] = field(default_factory=lambda: deque(maxlen=400))
    residuals: deque[tuple[float, float, float]] = field(default_factory=lambda: deque(maxlen=400))
    last: EscTelemetry | None = None
    diagnosis: Diagnosis | None = None
    health: str = "-"


class Monitor(Node):
    """Collects what ``thruster_ids`` publish (see module docstring); the node is ``name``."""

    def __init__(self, thruster_ids: list[str], name: str) -> None:
        super().__init__(name)
        self.rows = {tid: _Row() for tid in thruster_ids}
        # Topics the recorder's subscriptions have matched a publisher on (its status'
        # ``matched``), the latest it reported.
        self.recorder_matched: set[str] = set()
        # The bag folder the recorder reports writing (its status' ``bag``), empty until then.
        self.recorder_bag = ""
        reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        sensor = qos_profile_sensor_data
        ids = thruster_ids
        subscribe_thrusters(self, ids, EscTelemetry, "esc/telemetry", self._on_telemetry, sensor)
        subscribe_thrusters(self, ids, Residual, "fdd/residual", self._on_residual, sensor)
        subscribe_thrusters(self, ids, Diagnosis, "fdd/diagnosis", self._on_diagnosis, reliable)
        self.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            self._on_diagnostics,
            reliable,
            event_callbacks=NO_SUB_EVENTS,
        )

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_telemetry(self, tid: str, msg: EscTelemetry) -> None:
        row = self.rows[tid]
        row.last = msg
        row.stamps.append(self._now_s())

    def _on_diagnosis(self, tid: str, msg: Diagnosis) -> None:
        self.rows[tid].diagnosis = msg

    def _on_residual(self, tid: str, msg: Residual) -> None:
        if msg.flags == Residual.OK:
            self.rows[tid].residuals.append(
                (self._now_s(), msg.residual_rpm, msg.residual_current_a)
            )

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == status_name("recorder"):
                for kv in status.values:
                    if kv.key == "matched":
                        self.recorder_matched = set(filter(None, kv.value.split(",")))
                    elif kv.key == "bag":
                        self.recorder_bag = kv.value
            for tid, row in self.rows.items():
                if status.name == status_name("esc", tid):
                    row.health = f"{LEVELS.get(status.level[0], '?')}: {status.message}"

    def rate_hz(self, tid: str) -> float:
        """Telemetry messages per second received for ``tid`` over the last 2 s."""
        now = self._now_s()
        return sum(1 for s in self.rows[tid].stamps if now - s <= WINDOW_S) / WINDOW_S

    def residual_rms(self, tid: str) -> tuple[float, float] | None:
        """RMS of the rpm and current residuals (rpm, A) over the last 2 s; None if none."""
        now = self._now_s()
        recent = [(r, i) for s, r, i in self.rows[tid].residuals if now - s <= WINDOW_S]
        if not recent:
            return None
        return (
            math.sqrt(sum(r * r for r, _ in recent) / len(recent)),
            math.sqrt(sum(i * i for _, i in recent) / len(recent)),
        )

    def table(self) -> str:
        """The live table, one line per thruster."""
        lines = [
            f"{'id':<4} {'rate Hz':>7} {'cmd':>6} {'pwm us':>6} {'V':>6} {'A':>6} "
            f"{'rpm':>7} {'temp C':>6} {'res rpm':>7} {'res A':>6}  {'diagnosis':<26} link"
        ]
        for tid, row in self.rows.items():
            m = row.last
            if m is None:
                lines.append(f"{tid:<4} {'-':>7}  (no telemetry yet)  {row.health}")
                continue
            rms = self.residual_rms(tid)
            res = f"{rms[0]:7.0f} {rms[1]:6.2f}" if rms else f"{'-':>7} {'-':>6}"
            d = row.diagnosis
            if d is None:
                diag = "-"
            elif d.reason:
                diag = f"{d.label}: {d.reason}"
            else:
                diag = f"{d.label} ({d.confidence:.2f})"
            lines.append(
                f"{tid:<4} {self.rate_hz(tid):7.1f} {m.command:6.2f} {m.pwm_us:6d} "
                f"{m.voltage_v:6.2f} {m.current_a:6.2f} {m.rpm:7.0f} {m.temperature_c:6.1f} "
                f"{res}  {diag:<26} {row.health}"
            )
        return "\n".join(lines)
