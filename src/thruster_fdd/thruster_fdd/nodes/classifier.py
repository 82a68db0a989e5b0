"""Classifier node: residuals -> the diagnosed condition of one thruster.

Subscribes to ``fdd/residual`` (which carries the model inputs with the residuals), runs
``core.diagnosis.stream.DiagnosisStream`` and publishes ``Diagnosis`` on ``fdd/diagnosis`` every
hop, plus a ``/diagnostics`` status: OK for the nominal classes at 15 V, WARN for low supply
voltage and for an unknown diagnosis (with its reason: outside the training region, low
excitation, ...), ERROR for faults, STALE when residuals stop (then the diagnosis becomes UNKNOWN
rather than repeating an old label). A fault is published only once the sequential test's
evidence, counted beyond the ``unit_allowance`` a healthy unit may show, reaches the threshold
set for ``false_alarms_per_hour``. Residuals made by another
nominal model than the one the classifier was trained with are refused (UNKNOWN, ERROR with
both model ids).

Setting the ``model_dir`` parameter at runtime loads a newly exported classifier without a
restart; one that fails the checks is refused (the parameter change fails with the reason) and
the old one keeps running. A classifier made for the nominal model whose residuals arrive now
runs at once; one made for another nominal model is staged and takes over at the first residual
of that model, so ``thruster-fdd reload`` changes the pair atomically: each residual is always
diagnosed by the classifier made for its nominal model. While a model is staged, another
``model_dir`` is refused (one reload at a time) but the staged one again, or the running one,
which cancels the stage. The other parameters are read at start
only (a change is refused).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from thruster_fdd_msgs.msg import Diagnosis, Residual

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.core.diagnosis.model import ClassifierModel
from thruster_fdd.core.diagnosis.stream import (
    FALSE_ALARMS_PER_HOUR,
    UNIT_ALLOWANCE,
    Decision,
    DiagnosisStream,
)
from thruster_fdd.core.labels import UNKNOWN
from thruster_fdd.nodes.common import (
    NO_PUB_EVENTS,
    NO_SUB_EVENTS,
    RELIABLE_10,
    RecordSink,
    declare_parameters,
    diagnostics_publisher,
    publish_recorded,
    publish_status,
    refuse_start_only,
    run,
    status_name,
)
from thruster_fdd.nodes.nominal_model import NominalModelNode

CONDITION_CODES = {
    "nominal_15v": Diagnosis.NOMINAL_15V,
    "nominal_13v": Diagnosis.NOMINAL_13V,
    "nominal_11v8": Diagnosis.NOMINAL_11V8,
    "broken_blade_1": Diagnosis.BROKEN_BLADE_1,
    "broken_blade_2": Diagnosis.BROKEN_BLADE_2,
    "biofouling": Diagnosis.BIOFOULING,
}
LOW_VOLTAGE = ("nominal_13v", "nominal_11v8")
# Reliable, transient-local and deep, like the residual publisher: a window decision takes
# longer than one sample period and a replay runs far faster than real time, so the queue
# absorbs the backlog; a classifier that matches the publisher late still gets the history.
INPUT_QOS = QoSProfile(
    depth=500,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

PARAMETERS: tuple[tuple[str, object, str], ...] = (
    ("thruster_id", "t0", "thruster id written into every message"),
    ("model_dir", "", "exported classifier folder (empty: <models>/classifier)"),
    ("hop_s", 1.0, "time between two decisions, s"),
    ("hysteresis", 2, "consecutive equal window decisions needed to change the published label"),
    ("unknown_threshold", -1.0, "UNKNOWN threshold (negative: the model card's)"),
    (
        "false_alarms_per_hour",
        FALSE_ALARMS_PER_HOUR,
        "false-alarm rate the fault evidence threshold is set for, per hour of covered operation "
        "(lower: fewer false alarms, later detection)",
    ),
    (
        "unit_allowance",
        UNIT_ALLOWANCE,
        "evidence allowance against healthy thrusters: set it above the largest quiet allowance "
        "(thruster-fdd diagnose) of healthy units the classifier was not trained on, nats (per "
        "window length)",
    ),
    ("stale_after_s", 3.0, "no residual for this long -> STALE and UNKNOWN, s"),
    ("diagnostics_period_s", 1.0, "period of the /diagnostics status, s"),
)


def stream_options(value: Callable[[str], Any]) -> dict[str, Any]:
    """The ``DiagnosisStream`` options from the node's parameters (``value``: a parameter's
    value by name), as the node makes its stream; ``up`` checks a model with the defaults."""
    threshold = float(value("unknown_threshold"))
    return {
        "hop_s": float(value("hop_s")),
        "hysteresis": int(value("hysteresis")),
        "unknown_threshold": threshold if threshold >= 0 else None,
        "false_alarms_per_hour": float(value("false_alarms_per_hour")),
        "unit_allowance": float(value("unit_allowance")),
    }


class ClassifierNode(Node):
    """Publishes the diagnosis of one thruster (see module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("classifier", **node_kwargs)
        self._model: ClassifierModel | None = None
        self._last: Decision | None = None
        self._holding: tuple[Decision, str] | None = None
        declare_parameters(self, PARAMETERS)
        p = self.get_parameter
        self._id = p("thruster_id").value
        model_dir = p("model_dir").value or str(default_models_dir() / "classifier")
        self._stream_options = stream_options(lambda name: p(name).value)
        self._activate(ClassifierModel.load(model_dir), model_dir)
        self._staged: tuple[ClassifierModel, str] | None = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._stale_after_s = float(p("stale_after_s").value)
        self._last_input_s: float | None = None
        self._mismatch = ""
        self._stale = False
        self._received = 0
        self._source_id = ""
        self._local_subscribers: list[Callable[[Diagnosis], None]] = []
        self._sink: RecordSink | None = None
        self._pub = self.create_publisher(
            Diagnosis, "fdd/diagnosis", RELIABLE_10, event_callbacks=NO_PUB_EVENTS
        )
        self._diag_pub = diagnostics_publisher(self)
        self._sub: Subscription | None = self.create_subscription(
            Residual, "fdd/residual", self._on_residual, INPUT_QOS, event_callbacks=NO_SUB_EVENTS
        )
        self.create_timer(float(p("diagnostics_period_s").value), self._publish_status)
        self.get_logger().info(
            f"thruster {self._id}: classifier {self._model.model_id} from {model_dir} "
            f"({len(self._model.class_names)} classes, window {self._model.window_s:g} s)"
        )

    def _activate(self, model: ClassifierModel, model_dir: str) -> None:
        """Run ``model`` from now on, with a fresh window and evidence. Until its first
        decision, the previous model's last decision is published again every hop (a reload
        opens no gap in monitoring), under the previous model's id."""
        if self._last is not None and self._model is not None:
            self._holding = (self._last, self._model.model_id)
        elif self._model is None:
            self._holding = None
        # else: a model replaced before its first decision; the diagnosis held stays held.
        self._model = model
        self._model_dir = model_dir
        self._stream = DiagnosisStream(model, **self._stream_options)
        self._last = None
        self._held_until_s = -math.inf

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        refused = refuse_start_only(params, PARAMETERS, {"model_dir"})
        if refused is not None:
            return refused
        for param in params:
            if param.name != "model_dir":
                continue
            model_dir = param.value or str(default_models_dir() / "classifier")
            if self._staged is not None and model_dir not in (self._staged[1], self._model_dir):
                # One reload at a time: replacing a staged model would break the pair whose
                # nominal model is being loaded now.
                staged = self._staged[0]
                reason = (
                    f"a reload is in progress: {staged.model_id} is staged for the first "
                    f"residual of nominal model {staged.nominal_model_id}; set model_dir back "
                    f"to {self._model_dir} to cancel it"
                )
                self.get_logger().warning(f"refused {model_dir}: {reason}")
                return SetParametersResult(successful=False, reason=reason)
            try:
                model = ClassifierModel.load(model_dir)
            except ValueError as exc:
                self.get_logger().error(f"refused new model, keeping {self._model.model_id}: {exc}")
                return SetParametersResult(successful=False, reason=str(exc))
            running = self._source_id or self._model.nominal_model_id
            if model.nominal_model_id == running:
                self._staged = None
                self._activate(model, model_dir)
                self.get_logger().info(f"loaded model {model.model_id} from {model_dir}")
                return SetParametersResult(successful=True, reason=f"running {model.model_id}")
            self._staged = (model, model_dir)
            reason = (
                f"staged {model.model_id}: runs from the first residual of nominal model "
                f"{model.nominal_model_id} (now {running})"
            )
            self.get_logger().info(reason)
            return SetParametersResult(successful=True, reason=reason)
        return SetParametersResult(successful=True)

    def record_to(self, sink: RecordSink) -> tuple[str, ...]:
        """Hand every message of ``fdd/diagnosis`` to ``sink`` (the recorder of this process, which
        then does not subscribe to it over DDS); returns it, fully qualified."""
        self._sink = sink
        return (self.resolve_topic_name("fdd/diagnosis"),)

    def add_local_subscriber(self, callback: Callable[[Diagnosis], None]) -> None:
        """Also hand every published diagnosis to ``callback``, in this process (the health
        node of a container), before the DDS write."""
        self._local_subscribers.append(callback)

    def take_residuals_from(self, source: NominalModelNode) -> None:
        """Get residuals from ``source``, a nominal-model node in this process, not from DDS.

        Replaces the ``fdd/residual`` subscription by intra-process delivery (the container
        does this when it hosts both stages of a thruster): the hop from residual to decision
        does not wait for DDS and the executor (``bench/bench_latency.py``).
        """
        if self._sub is not None:
            self.destroy_subscription(self._sub)
            self._sub = None
        source.add_local_subscriber(self._on_residual)

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_residual(self, msg: Residual) -> None:
        self._received += 1
        self._last_input_s = self._now_s()
        self._stale = False
        self._source_id = msg.model_id
        if self._staged is not None and msg.model_id == self._staged[0].nominal_model_id:
            model, model_dir = self._staged
            self._staged = None
            self._activate(model, model_dir)
            self.get_logger().info(f"now running staged model {model.model_id} from {model_dir}")
        if msg.model_id != self._model.nominal_model_id:
            self._mismatch = (
                f"residuals from nominal model {msg.model_id}, classifier trained on "
                f"{self._model.nominal_model_id}"
            )
            return
        self._mismatch = ""
        decision = self._stream.push(
            msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9,
            msg.command,
            msg.voltage_v,
            msg.measured_rpm,
            msg.measured_current_a,
            msg.residual_rpm,
            msg.residual_current_a,
            # The same validity as core.nominal.residuals.ResidualSample.valid (offline diagnosis).
            not msg.flags & (Residual.WARMING_UP | Residual.INPUT_INVALID),
        )
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if decision is not None:
            self._last = decision
            self._holding = None
            self._publish(decision, msg.header)
        elif self._holding is not None and stamp >= self._held_until_s:
            held, model_id = self._holding
            self._held_until_s = stamp + self._stream.hop_s
            self._publish(held, msg.header, model_id=model_id)

    def _publish(
        self,
        decision: Decision,
        header: object | None = None,
        reason: str = "",
        model_id: str | None = None,
    ) -> None:
        out = Diagnosis(
            thruster_id=self._id,
            condition=CONDITION_CODES.get(decision.label, Diagnosis.UNKNOWN),
            label=decision.label,
            class_names=list(decision.probabilities),
            probabilities=[float(v) for v in decision.probabilities.values()],
            confidence=float(decision.confidence),
            window_s=float(decision.window_s),
            model_id=model_id or self._model.model_id,
            reason=reason or decision.reason,
            covered=decision.covered,
            fault_evidence=_finite(decision.fault_evidence),
            fault_candidate=decision.fault_candidate,
            fault_threshold=_finite(decision.fault_threshold),
        )
        if header is not None:
            out.header = header
        else:
            out.header.stamp = self.get_clock().now().to_msg()
        out.header.frame_id = self._id
        for callback in self._local_subscribers:
            callback(out)
        publish_recorded(self._pub, out, self._sink)

    def _publish_status(self) -> None:
        now = self._now_s()
        silent = self._last_input_s is None or now - self._last_input_s > self._stale_after_s
        if silent and not self._stale:
            # Say UNKNOWN once instead of letting subscribers keep an old label.
            self._stale = True
            self._stream.reset()
            self._last = None
            self._holding = None
            uniform = 1.0 / len(self._model.class_names)
            self._publish(
                Decision(
                    t_s=now,
                    label=UNKNOWN,
                    raw_label=UNKNOWN,
                    probabilities=dict.fromkeys(self._model.class_names, uniform),
                    confidence=0.0,
                    window_s=0.0,
                    t_start_s=now,
                    distance=math.inf,
                    fault_threshold=self._stream.threshold,
                ),
                reason="stale",
            )
        last = self._last or (self._holding[0] if self._holding else None)
        label = last.label if last is not None else UNKNOWN
        if self._holding is not None and not silent and not self._mismatch:
            level, message = (
                DiagnosticStatus.WARN,
                f"reload in progress: {self._model.model_id} warming up, "
                f"{self._holding[1]}'s last diagnosis {label} held",
            )
        elif self._mismatch:
            level, message = DiagnosticStatus.ERROR, self._mismatch
        elif silent:
            level, message = DiagnosticStatus.STALE, "no residuals: diagnosis unknown"
        elif self._last is None:
            level, message = DiagnosticStatus.WARN, "diagnosis unknown: window filling"
        elif label == UNKNOWN:
            why = self._last.reason.replace("_", " ")
            level, message = DiagnosticStatus.WARN, f"diagnosis unknown: {why}"
        elif label.startswith("nominal") and label not in LOW_VOLTAGE:
            level, message = DiagnosticStatus.OK, f"{label} ({self._last.confidence:.2f})"
        elif label in LOW_VOLTAGE:
            level, message = DiagnosticStatus.WARN, f"low supply voltage: {label}"
        else:
            level, message = DiagnosticStatus.ERROR, f"fault: {label} ({self._last.confidence:.2f})"
        publish_status(
            self,
            self._diag_pub,
            level,
            status_name("classifier", self._id),
            message,
            self._id,
            [
                ("label", label),
                ("reason", self._last.reason if self._last is not None else "warming_up"),
                ("covered", str(self._last.covered if self._last is not None else False)),
                (
                    "fault_evidence",
                    f"{self._last.fault_evidence:.2f} of {self._stream.threshold:.2f} nats"
                    if self._last is not None
                    else "0",
                ),
                ("residuals_received", str(self._received)),
                ("model_id", self._model.model_id),
                ("nominal_model_id", self._model.nominal_model_id),
                ("model_dir", self._model_dir),
                ("staged_model_id", self._staged[0].model_id if self._staged else ""),
            ],
        )


def _finite(value: float) -> float:
    """``value``, or 0 when it is not finite (every published float is finite)."""
    return float(value) if math.isfinite(value) else 0.0


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C; exit 1 with the reason when the model cannot be used."""
    run(ClassifierNode, args)


if __name__ == "__main__":
    main()
