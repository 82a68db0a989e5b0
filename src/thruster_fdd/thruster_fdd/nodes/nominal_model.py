"""Nominal-model node: telemetry -> residuals of the exported healthy-thruster NARX model.

Subscribes to ``esc/telemetry``, feeds the model at its sample time (``core.nominal.residuals``),
publishes ``Residual`` on ``fdd/residual`` and a status on ``/diagnostics`` (rates, step times,
the RMS of the period's OK residuals). A missing, corrupt or mismatched model stops the node at
start with a message naming the file and what is wrong.
Setting the ``model_dir`` parameter at runtime loads a newly exported model without a restart;
a model that fails the checks is refused (the parameter change fails with the reason) and the
old one keeps running. The other parameters are read at start only (a change is refused).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.subscription import Subscription
from thruster_fdd_msgs.msg import EscTelemetry, Residual

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.core.nominal.residuals import ResidualSample, ResidualStream
from thruster_fdd.core.nominal.runtime import NominalModel
from thruster_fdd.nodes.common import (
    NO_PUB_EVENTS,
    NO_SUB_EVENTS,
    Limit,
    RecordSink,
    declare_parameters,
    diagnostics_publisher,
    publish_recorded,
    publish_status,
    refuse_start_only,
    run,
    status_name,
)

if TYPE_CHECKING:
    from thruster_fdd.nodes.esc_driver import EscDriver

# Reliable and transient-local with a deep history: a classifier busy with a window decision
# catches up without losing samples, and one that joins late still gets the last 50 s of
# residuals (volatile and sensor-data subscribers still match).
RESIDUAL_QOS = QoSProfile(
    depth=500,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# Telemetry for a replay: reliable, so a fast replayer can keep many samples in flight and
# none is lost. A best-effort publisher (the ESC driver) does not match it.
REPLAY_TELEMETRY_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)

PARAMETERS: tuple[tuple[str, object, str], ...] = (
    ("thruster_id", "t0", "thruster id written into every message"),
    ("model_dir", "", "exported nominal model folder (empty: <models>/nominal)"),
    ("max_gap_periods", 3.0, "a telemetry gap longer than this many model periods resets state"),
    ("diagnostics_period_s", 1.0, "period of the /diagnostics status, s"),
    (
        "reliable_telemetry",
        False,
        "subscribe to esc/telemetry reliable, depth 1000 (replay), not sensor data (driver)",
    ),
)
LIMITS: dict[str, Limit] = {
    "max_gap_periods": (1.0, 1000.0),
    "diagnostics_period_s": (0.01, 3600.0),
}
"""Ranges in the descriptors (``ros2 param describe``, ``nominal_model --help``)."""


def residual_message(
    thruster_id: str, model_id: str, telemetry: EscTelemetry, out: ResidualSample
) -> Residual:
    """The ``Residual`` of one telemetry sample, every float field finite.

    A non-finite input (the stream then flags the sample ``INPUT_INVALID``) or an output that
    overflowed is published as 0 with ``INPUT_INVALID`` set: a subscriber never sees NaN or inf.

    Parameters
    ----------
    thruster_id, model_id : str
        Written into the message.
    telemetry : EscTelemetry
        The sample; its header and its command and voltage (the model's inputs) are copied.
    out : ResidualSample
        What the residual stream made of it.
    """
    values = {
        "command": telemetry.command,
        "voltage_v": telemetry.voltage_v,
        "measured_rpm": out.measured_rpm,
        "predicted_rpm": out.predicted_rpm,
        "residual_rpm": out.residual_rpm,
        "measured_current_a": out.measured_current_a,
        "predicted_current_a": out.predicted_current_a,
        "residual_current_a": out.residual_current_a,
    }
    flags = out.flags
    if not all(math.isfinite(v) for v in values.values()):
        flags |= Residual.INPUT_INVALID
        values = {k: v if math.isfinite(v) else 0.0 for k, v in values.items()}
    res = Residual(thruster_id=thruster_id, flags=flags, model_id=model_id, **values)
    res.header = telemetry.header
    return res


class NominalModelNode(Node):
    """Publishes the residuals of one thruster (see module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("nominal_model", **node_kwargs)
        declare_parameters(self, PARAMETERS, LIMITS)
        p = self.get_parameter
        self._id = p("thruster_id").value
        model_dir = p("model_dir").value or str(default_models_dir() / "nominal")
        self._max_gap_periods = float(p("max_gap_periods").value)
        self._model = NominalModel.load(model_dir)
        self._stream = ResidualStream(self._model, self._max_gap_periods)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._pub = self.create_publisher(
            Residual, "fdd/residual", RESIDUAL_QOS, event_callbacks=NO_PUB_EVENTS
        )
        self._diag_pub = diagnostics_publisher(self)
        telemetry_qos = (
            REPLAY_TELEMETRY_QOS if p("reliable_telemetry").value else qos_profile_sensor_data
        )
        self._telemetry_sub: Subscription | None = self.create_subscription(
            EscTelemetry,
            "esc/telemetry",
            self._on_telemetry,
            telemetry_qos,
            event_callbacks=NO_SUB_EVENTS,
        )
        self._diag_period_s = float(p("diagnostics_period_s").value)
        if not 0.0 < self._diag_period_s < math.inf:
            raise ValueError(f"diagnostics_period_s must be > 0, got {self._diag_period_s}")
        self.create_timer(self._diag_period_s, self._publish_diagnostics)
        self._published = 0
        self._window_published = 0
        # Of the window's OK residuals: count and sums of squares (rpm, A), for the RMS in the
        # status, which a live view reads instead of the 50 Hz topic.
        self._ok_residuals = 0
        self._sq_rpm = 0.0
        self._sq_current = 0.0
        self._last_reason = ""
        self._step_s: list[float] = []
        self._local_subscribers: list[Callable[[Residual], None]] = []
        self._sink: RecordSink | None = None
        self.get_logger().info(
            f"thruster {self._id}: model {self._model.model_id} from {model_dir} "
            f"({self._model.card.mode}, {1.0 / self._model.sample_time_s:g} Hz)"
        )

    def add_local_subscriber(self, callback: Callable[[Residual], None]) -> None:
        """Also hand every published residual to ``callback``, in this process.

        Intra-process delivery, as rclcpp does it for composed nodes: a node in the same
        process gets the message object without a trip through DDS and the executor, and
        before the DDS write, so the diagnosis does not wait for it. ``fdd/residual`` still
        goes out on DDS for every other subscriber.
        """
        self._local_subscribers.append(callback)

    def record_to(self, sink: RecordSink) -> tuple[str, ...]:
        """Hand every message of ``fdd/residual`` to ``sink`` (the recorder of this process, which
        then does not subscribe to it over DDS); returns it, fully qualified."""
        self._sink = sink
        return (self.resolve_topic_name("fdd/residual"),)

    def take_telemetry_from(self, source: EscDriver) -> None:
        """Get telemetry from ``source``, the ESC driver of this thruster in this process.

        Replaces the ``esc/telemetry`` subscription by intra-process delivery (the container
        does this when it hosts the driver too): the sample reaches the model without DDS and
        the executor (``bench/bench_latency.py``).
        """
        if self._telemetry_sub is not None:
            self.destroy_subscription(self._telemetry_sub)
            self._telemetry_sub = None
        source.add_local_subscriber(self._on_telemetry)

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        refused = refuse_start_only(params, PARAMETERS, {"model_dir"})
        if refused is not None:
            return refused
        for param in params:
            if param.name != "model_dir":
                continue
            try:
                model = NominalModel.load(param.value or str(default_models_dir() / "nominal"))
            except ValueError as exc:
                self.get_logger().error(f"refused new model, keeping {self._model.model_id}: {exc}")
                return SetParametersResult(successful=False, reason=str(exc))
            self._model = model
            self._stream = ResidualStream(model, self._max_gap_periods)
            self.get_logger().info(f"loaded model {model.model_id} from {param.value}")
            return SetParametersResult(successful=True, reason=f"running {model.model_id}")
        return SetParametersResult(successful=True)

    def _on_telemetry(self, msg: EscTelemetry) -> None:
        t_s = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        start = time.perf_counter()
        out = self._stream.push(
            t_s, msg.command, msg.voltage_v, msg.rpm, msg.current_a, msg.sequence
        )
        if out is None:
            return
        self._step_s.append(time.perf_counter() - start)
        if out.reason:
            self._last_reason = out.reason
        res = residual_message(self._id, self._model.model_id, msg, out)
        if res.flags == Residual.OK:
            self._ok_residuals += 1
            self._sq_rpm += res.residual_rpm * res.residual_rpm
            self._sq_current += res.residual_current_a * res.residual_current_a
        for callback in self._local_subscribers:
            callback(res)
        publish_recorded(self._pub, res, self._sink)
        self._published += 1

    def _publish_diagnostics(self) -> None:
        count = self._published - self._window_published
        self._window_published = self._published
        rate = count / self._diag_period_s
        steps = sorted(self._step_s)
        self._step_s.clear()
        median_us = 1e6 * steps[len(steps) // 2] if steps else 0.0
        p99_us = 1e6 * steps[min(len(steps) - 1, int(0.99 * len(steps)))] if steps else 0.0
        if count == 0:
            level, message = DiagnosticStatus.STALE, "no telemetry to model"
        elif self._last_reason:
            level, message = DiagnosticStatus.WARN, f"state reset: {self._last_reason}"
        else:
            level, message = DiagnosticStatus.OK, f"residuals {rate:.1f} Hz"
        self._last_reason = ""
        n_ok = self._ok_residuals
        rms_rpm = f"{math.sqrt(self._sq_rpm / n_ok):.1f}" if n_ok else "-"
        rms_a = f"{math.sqrt(self._sq_current / n_ok):.3f}" if n_ok else "-"
        self._ok_residuals, self._sq_rpm, self._sq_current = 0, 0.0, 0.0
        publish_status(
            self,
            self._diag_pub,
            level,
            status_name("nominal_model", self._id),
            message,
            self._id,
            [
                ("residual_rate_hz", f"{rate:.1f}"),
                ("residuals_published", str(self._published)),
                ("model_id", self._model.model_id),
                ("resets", str(self._stream.resets)),
                ("invalid_samples", str(self._stream.invalid)),
                ("median_step_us", f"{median_us:.0f}"),
                ("p99_step_us", f"{p99_us:.0f}"),
                ("rms_residual_rpm", rms_rpm),
                ("rms_residual_a", rms_a),
            ],
        )


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C; exit 1 with the reason when the model cannot be used."""
    run(NominalModelNode, args)


if __name__ == "__main__":
    main()
