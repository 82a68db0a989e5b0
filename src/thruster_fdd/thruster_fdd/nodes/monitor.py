"""Monitor node: a live table of every thruster's telemetry and link health.

Subscribes to ``/thruster/<id>/esc/telemetry`` of the given thrusters and to ``/diagnostics``,
and renders one row per thruster: telemetry rate, command, pwm, voltage, current, rpm,
temperature and the driver's health message. ``thruster-fdd up`` prints it every few seconds.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from thruster_fdd_msgs.msg import EscTelemetry

LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


@dataclass
class _Row:
    """The latest state of one thruster (mutable: updated by callbacks)."""

    stamps: deque[float]
    last: EscTelemetry | None = None
    health: str = "-"


class Monitor(Node):
    """Collects telemetry and diagnostics of ``thruster_ids`` (see module docstring)."""

    def __init__(self, thruster_ids: list[str]) -> None:
        super().__init__("monitor")
        self.rows = {tid: _Row(stamps=deque(maxlen=400)) for tid in thruster_ids}
        for tid in thruster_ids:
            self.create_subscription(
                EscTelemetry,
                f"/thruster/{tid}/esc/telemetry",
                lambda msg, tid=tid: self._on_telemetry(tid, msg),
                qos_profile_sensor_data,
            )
        self.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            self._on_diagnostics,
            QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE),
        )

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_telemetry(self, tid: str, msg: EscTelemetry) -> None:
        row = self.rows[tid]
        row.last = msg
        row.stamps.append(self._now_s())

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            for tid, row in self.rows.items():
                if status.name == f"/thruster/{tid}/esc_driver":
                    level = LEVELS.get(status.level[0], "?")
                    row.health = f"{level}: {status.message}"

    def rate_hz(self, tid: str, window_s: float = 2.0) -> float:
        """Telemetry messages per second received for ``tid`` over the last ``window_s``."""
        now = self._now_s()
        return sum(1 for s in self.rows[tid].stamps if now - s <= window_s) / window_s

    def table(self) -> str:
        """The live table, one line per thruster."""
        lines = [
            f"{'id':<4} {'rate Hz':>7} {'cmd':>6} {'pwm us':>6} {'V':>6} {'A':>6} "
            f"{'rpm':>7} {'temp C':>6}  link"
        ]
        for tid, row in self.rows.items():
            m = row.last
            if m is None:
                lines.append(f"{tid:<4} {'-':>7}  (no telemetry yet)  {row.health}")
                continue
            lines.append(
                f"{tid:<4} {self.rate_hz(tid):7.1f} {m.command:6.2f} {m.pwm_us:6d} "
                f"{m.voltage_v:6.2f} {m.current_a:6.2f} {m.rpm:7.0f} {m.temperature_c:6.1f}  "
                f"{row.health}"
            )
        return "\n".join(lines)
