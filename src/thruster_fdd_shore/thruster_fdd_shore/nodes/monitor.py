"""Monitor node: a live table of every thruster's telemetry, residuals, diagnosis and health.

Reads the once-per-period summaries on ``/diagnostics`` rather than the 50 Hz topics (every
subscriber of ``esc/telemetry`` or ``fdd/residual`` costs the vehicle's publisher): the
``esc <id>`` status gives the telemetry rate, the newest published sample and the link's health,
the ``nominal_model <id>`` status the RMS of the period's OK residuals. Only ``fdd/diagnosis``
(a few Hz) is subscribed to, per thruster under ``/thruster/<id>``. One row per thruster:
telemetry rate, command, pwm, voltage, current, rpm, temperature, RMS residuals, the diagnosis
and the driver's health message. ``thruster-fdd up`` prints it every few seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from thruster_fdd_msgs.msg import Diagnosis

from thruster_fdd.nodes.common import NO_SUB_EVENTS, status_name, subscribe_thrusters

LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
STATUS_STALE_S = 5.0
"""A driver status older than this is shown as STALE: the row's values are its last words."""

# (status key, column width) of the table's columns, in order.
ESC_COLUMNS: tuple[tuple[str, int], ...] = (
    ("telemetry_rate_hz", 7),
    ("command", 6),
    ("pwm_us", 6),
    ("voltage_v", 6),
    ("current_a", 6),
    ("rpm", 7),
    ("temperature_c", 6),
)
MODEL_COLUMNS: tuple[tuple[str, int], ...] = (("rms_residual_rpm", 7), ("rms_residual_a", 6))


@dataclass
class _Row:
    """The latest state of one thruster (mutable: updated by callbacks).

    Attributes
    ----------
    esc, model : dict[str, str]
        Key/values of the newest ``esc <id>`` and ``nominal_model <id>`` statuses.
    esc_seen_s : float or None
        When that ``esc`` status arrived (the node's clock), s; None before the first.
    diagnosis : Diagnosis or None
        The newest diagnosis.
    health : str
        The ``esc`` status' level and message.
    """

    esc: dict[str, str] = field(default_factory=dict)
    esc_seen_s: float | None = None
    model: dict[str, str] = field(default_factory=dict)
    diagnosis: Diagnosis | None = None
    health: str = "-"


def _cells(values: dict[str, str], columns: tuple[tuple[str, int], ...]) -> str:
    """The status values of ``columns``, right-aligned to their widths ("-" when absent)."""
    return " ".join(f"{values.get(key, '-'):>{width}}" for key, width in columns)


class Monitor(Node):
    """Collects what ``thruster_ids`` report (see module docstring); the node is ``name``."""

    def __init__(self, thruster_ids: list[str], name: str) -> None:
        super().__init__(name)
        self.rows = {tid: _Row() for tid in thruster_ids}
        # Topics the recorder's subscriptions have matched a publisher on (its status'
        # ``matched``), the latest it reported.
        self.recorder_matched: set[str] = set()
        # The bag folder the recorder reports writing (its status' ``bag``), empty until then.
        self.recorder_bag = ""
        reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        subscribe_thrusters(
            self, thruster_ids, Diagnosis, "fdd/diagnosis", self._on_diagnosis, reliable
        )
        self.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            self._on_diagnostics,
            reliable,
            event_callbacks=NO_SUB_EVENTS,
        )

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_diagnosis(self, tid: str, msg: Diagnosis) -> None:
        self.rows[tid].diagnosis = msg

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if status.name == status_name("recorder"):
                if "matched" in values:
                    self.recorder_matched = set(filter(None, values["matched"].split(",")))
                if "bag" in values:
                    self.recorder_bag = values["bag"]
            for tid, row in self.rows.items():
                if status.name == status_name("esc", tid):
                    row.esc = values
                    row.esc_seen_s = self._now_s()
                    row.health = f"{LEVELS.get(status.level[0], '?')}: {status.message}"
                elif status.name == status_name("nominal_model", tid):
                    row.model = values

    def table(self) -> str:
        """The live table, one line per thruster."""
        lines = [
            f"{'id':<4} {'rate Hz':>7} {'cmd':>6} {'pwm us':>6} {'V':>6} {'A':>6} "
            f"{'rpm':>7} {'temp C':>6} {'res rpm':>7} {'res A':>6}  {'diagnosis':<26} link"
        ]
        now = self._now_s()
        for tid, row in self.rows.items():
            health = row.health
            if row.esc_seen_s is not None and now - row.esc_seen_s > STATUS_STALE_S:
                health = f"STALE: no driver status for {now - row.esc_seen_s:.0f} s; {health}"
            if row.esc.get("rpm", "-") == "-":
                lines.append(f"{tid:<4} {'-':>7}  (no telemetry yet)  {health}")
                continue
            d = row.diagnosis
            if d is None:
                diag = "-"
            elif d.reason:
                diag = f"{d.label}: {d.reason}"
            else:
                diag = f"{d.label} ({d.confidence:.2f})"
            lines.append(
                f"{tid:<4} {_cells(row.esc, ESC_COLUMNS)} {_cells(row.model, MODEL_COLUMNS)}  "
                f"{diag:<26} {health}"
            )
        return "\n".join(lines)
