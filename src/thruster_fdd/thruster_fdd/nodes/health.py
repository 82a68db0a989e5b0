"""Health node: thrust available per thruster, for mission software and the thrust allocator.

Subscribes to every listed thruster's ``fdd/diagnosis`` and ``fdd/residual`` (which carries the
telemetry at the model's sample time) and publishes ``VehicleHealth`` on
``/thruster_fdd/health`` once a period and at once when a thruster's label, fault flag or
staleness changes: per thruster the diagnosis, a fault flag and the effectiveness estimate with
its uncertainty (``core.diagnosis.health``, ``core.diagnosis.effectiveness``), plus masks of
faulty and stale thrusters. A status on ``/diagnostics`` says whether diagnoses arrive.
"""

from __future__ import annotations

import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from thruster_fdd_msgs.msg import Diagnosis, Residual, ThrusterHealth, VehicleHealth

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.core.diagnosis.health import HealthTracker, masks
from thruster_fdd.core.diagnosis.reference import ThrustReference
from thruster_fdd.nodes.common import (
    NO_PUB_EVENTS,
    RELIABLE_10,
    RecordSink,
    declare_parameters,
    diagnostics_publisher,
    publish_recorded,
    publish_status,
    run,
    status_name,
    subscribe_thrusters,
)

HEALTH_TOPIC = "/thruster_fdd/health"
# Reliable and transient local with depth 1: mission software that starts late gets the latest
# health at once, as with a latched status.
HEALTH_QOS = QoSProfile(
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# The residual publisher is reliable and transient local; a volatile reader matches it and
# starts with what comes next (old samples would only delay the estimate).
RESIDUAL_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)

PARAMETERS: tuple[tuple[str, object, str], ...] = (
    ("thruster_ids", ["t0"], "thrusters reported, in this order (bit i of the masks)"),
    (
        "reference",
        "",
        "folder of the thruster type's reference load curves (thruster-fdd reference); "
        "empty: the models folder's reference/",
    ),
    ("period_s", 1.0, "period of /thruster_fdd/health, s (also published on every change)"),
    ("stale_after_s", 3.0, "no diagnosis for this long -> stale and unknown, s"),
    ("diagnostics_period_s", 1.0, "period of the /diagnostics status, s"),
)


class HealthNode(Node):
    """Publishes the vehicle's thruster health (see module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("health", **node_kwargs)
        declare_parameters(self, PARAMETERS)
        p = self.get_parameter
        ids = [str(tid) for tid in p("thruster_ids").value]
        folder = str(p("reference").value) or str(default_models_dir() / "reference")
        reference = ThrustReference.load(folder)
        self._tracker = HealthTracker(ids, reference, float(p("stale_after_s").value))
        self._pub = self.create_publisher(
            VehicleHealth, HEALTH_TOPIC, HEALTH_QOS, event_callbacks=NO_PUB_EVENTS
        )
        self._diag_pub = diagnostics_publisher(self)
        self._received = dict.fromkeys(ids, 0)
        self._sink: RecordSink | None = None
        self._subs = {
            "fdd/diagnosis": subscribe_thrusters(
                self, ids, Diagnosis, "fdd/diagnosis", self._on_diagnosis, RELIABLE_10
            ),
            "fdd/residual": subscribe_thrusters(
                self, ids, Residual, "fdd/residual", self._on_residual, RESIDUAL_QOS
            ),
        }
        self.create_timer(float(p("period_s").value), self._publish)
        self.create_timer(float(p("diagnostics_period_s").value), self._publish_status)
        self.get_logger().info(
            f"health of {', '.join(ids)} on {HEALTH_TOPIC} (reference: {reference.name})"
        )

    def take_from(self, tid: str, nominal_model: Any, classifier: Any | None) -> None:
        """Get thruster ``tid``'s residuals and diagnoses from its nodes in this process
        (``NominalModelNode``, ``ClassifierNode``; the classifier may be missing) by direct
        calls instead of DDS: the container does this when one executor runs them all."""
        for topic, source, callback in (
            ("fdd/residual", nominal_model, self._on_residual),
            ("fdd/diagnosis", classifier, self._on_diagnosis),
        ):
            if source is None:
                continue
            self.destroy_subscription(self._subs[topic].pop(tid))
            source.add_local_subscriber(lambda msg, tid=tid, callback=callback: callback(tid, msg))

    def record_to(self, sink: RecordSink) -> tuple[str, ...]:
        """Hand every ``VehicleHealth`` published to ``sink`` (the recorder of this process,
        which then does not subscribe to it over DDS); returns the topic."""
        self._sink = sink
        return (HEALTH_TOPIC,)

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_diagnosis(self, tid: str, msg: Diagnosis) -> None:
        self._received[tid] += 1
        now = self._now_s()
        self._tracker.add_diagnosis(tid, msg.label, msg.confidence, now, msg.reason)
        if self._tracker.changed(now):
            self._publish()

    def _on_residual(self, tid: str, msg: Residual) -> None:
        if msg.flags & Residual.INPUT_INVALID:
            return
        stamp = msg.header.stamp
        self._tracker.add_sample(
            tid,
            stamp.sec + stamp.nanosec * 1e-9,
            msg.command,
            msg.voltage_v,
            msg.measured_rpm,
            msg.measured_current_a,
        )

    def _publish(self) -> None:
        now = self._now_s()
        self._tracker.changed(now)  # a change noticed here is published now, not again
        entries = self._tracker.snapshot(now)
        faulty, stale = masks(entries)
        out = VehicleHealth(faulty_mask=faulty, stale_mask=stale)
        out.header.stamp = self.get_clock().now().to_msg()
        for e in entries:
            eff = e.effectiveness
            out.thrusters.append(
                ThrusterHealth(
                    thruster_id=e.thruster_id,
                    condition=e.condition,
                    label=e.label,
                    confidence=_finite(e.confidence, 0.0),
                    faulty=e.faulty,
                    stale=e.stale,
                    effectiveness=_finite(eff.value, 1.0),
                    effectiveness_std=_finite(eff.std, 0.5),
                    effectiveness_source=ThrusterHealth.ESTIMATED
                    if eff.family
                    else ThrusterHealth.NO_EVIDENCE,
                    fitted_fault=eff.family,
                    fitted_severity=_finite(eff.severity, 0.0),
                    label_age_s=_finite(e.label_age_s, 0.0),
                    unknown_reason=e.unknown_reason,
                )
            )
        publish_recorded(self._pub, out, self._sink)

    def _publish_status(self) -> None:
        entries = self._tracker.snapshot(self._now_s())
        stale = [e.thruster_id for e in entries if e.stale]
        if len(stale) == len(entries):
            level, message = DiagnosticStatus.STALE, "no diagnoses"
        elif stale:
            level, message = DiagnosticStatus.WARN, f"no diagnoses of {', '.join(stale)}"
        else:
            level, message = DiagnosticStatus.OK, f"health of {len(entries)} thruster(s)"
        old = [e.thruster_id for e in entries if not e.stale and e.unknown_reason]
        if old and level == DiagnosticStatus.OK:
            level = DiagnosticStatus.WARN
            message = f"diagnosis unknown now, last trustworthy label kept: {', '.join(old)}"
        values = [("thrusters", ",".join(e.thruster_id for e in entries))]
        for e in entries:
            eff = e.effectiveness
            values.append((f"{e.thruster_id}.effectiveness", f"{eff.value:.3f} +- {eff.std:.3f}"))
            values.append((f"{e.thruster_id}.label", e.label))
            values.append((f"{e.thruster_id}.label_age_s", f"{e.label_age_s:.1f}"))
            if e.unknown_reason:
                values.append((f"{e.thruster_id}.unknown_reason", e.unknown_reason))
            values.append(
                (f"{e.thruster_id}.diagnoses_received", str(self._received[e.thruster_id]))
            )
        publish_status(
            self, self._diag_pub, level, status_name("health"), message, "vehicle", values
        )


def _finite(value: float, fallback: float) -> float:
    """``value`` if finite, else ``fallback`` (every published float is finite)."""
    return float(value) if math.isfinite(value) else fallback


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C; exit 1 with the reason when it cannot start."""
    run(HealthNode, args)


if __name__ == "__main__":
    main()
