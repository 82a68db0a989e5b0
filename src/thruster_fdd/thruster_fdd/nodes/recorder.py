"""Recorder node: every topic of the graph, as raw CDR, into a rosbag2 bag of MCAP files.

Discovers topics periodically (new ones are picked up as they appear), subscribes with
``raw=True`` and the QoS its publishers offer (reliable only when every publisher is;
transient-local, deep, when every publisher is, so the history published before the recorder
matched — the first residuals of a run — is recorded too, as rosbag2 does), and hands the bytes
to a ``core.traces.bag_writer.BagWriter``, whose thread writes the bag folder
``<output_dir>/<prefix>`` (``<prefix>_2``, ... when that folder exists: a recorder writes only
into a folder it created) with its ``metadata.yaml``; the publishers' QoS profiles and type
hashes go into the bag (``ros2 bag play`` offers the same QoS again). Hosted in a container
(``container --vehicle recorder``), it takes the topics of that process's nodes from their
``record`` calls — the bytes they publish, and the commands the drivers take — and subscribes to
none of them. Its ``/diagnostics`` status lists in ``matched`` the topics whose subscription has
matched a publisher and the topics of its own process, published at once when that changes:
``up`` activates the drivers only when their telemetry is listed, so a bag holds every sample
the live models used (docs/contracts.md). A topic first seen through its subscribers only is
subscribed at once with the fallback QoS (best effort, volatile), and its publishers' QoS and
type hash are taken when they appear, as rosbag2's recorder adapts: looked up again at every
discovery and before the topic's first message is written. A type whose definition nobody has
is recorded with an empty definition. An unwritable folder or a full disk is reported on
``/diagnostics`` as ERROR (``dropped`` counts what was lost) while the node, the rest of its
process and the graph keep running; the writer tries again every second. Stopped by Ctrl-C or
by the death of the ``up`` that started it, it finishes the bag.
"""

from __future__ import annotations

import importlib
import re
import time
from collections.abc import Iterable
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from thruster_fdd.core.traces.bag_writer import BagWriter
from thruster_fdd.core.traces.recording import RecordingPolicy
from thruster_fdd.nodes.common import (
    Limit,
    declare_parameters,
    diagnostics_publisher,
    publish_status,
    run,
    status_name,
)

_THRUSTER_TOPIC = re.compile(r"^/thruster/([^/]+)/")
# At least the depth of the deepest transient-local publisher (fdd/residual keeps 500).
_LATCHED_DEPTH = 1000

PARAMETERS: tuple[tuple[str, object, str], ...] = (
    ("output_dir", "recordings", "folder of the bag folders (created if missing)"),
    ("prefix", "", "bag folder and file name (empty: the start time, YYYYmmdd_HHMMSS)"),
    ("include", ".*", "regex: record topics whose name matches"),
    ("exclude", ["/rosout", "/parameter_events"], "topics never recorded (exact names)"),
    ("discovery_period_s", 0.5, "how often new topics are looked for, s"),
    ("max_file_mb", 256.0, "split: start a new file past this size, MiB"),
    ("max_file_duration_s", 600.0, "split: start a new file past this span, s"),
    ("chunk_kb", 512, "MCAP chunk size before compression, KiB"),
    ("flush_period_s", 1.0, "write the chunk in progress at least this often, s"),
    ("compression", "zstd", "chunk compression: zstd, lz4 or none"),
    ("vehicle", "sim-auv", "vehicle name written into the file metadata"),
    ("model_ids", "", "ids of the models running, written into the metadata (up fills it)"),
    ("diagnostics_period_s", 1.0, "period of the /diagnostics status, s"),
)
LIMITS: dict[str, Limit] = {
    "discovery_period_s": (0.01, 60.0),
    "max_file_mb": (0.001, 1.0e6),
    "max_file_duration_s": (0.1, 1.0e6),
    "chunk_kb": (1, 1_000_000),
    "flush_period_s": (0.01, 3600.0),
    "compression": ("zstd", "lz4", "none"),
    "diagnostics_period_s": (0.01, 3600.0),
}
"""Ranges and allowed values in the descriptors (``ros2 param describe``, ``recorder --help``)."""


def _software_version() -> str:
    try:
        return version("thruster_fdd")
    except PackageNotFoundError:
        return "unknown"


def qos_profile_dict(qos: QoSProfile) -> dict[str, Any]:
    """A publisher's QoS as rosbag2 stores it (metadata version 9: policy names, durations as
    ``{sec, nsec}``)."""

    def duration(d: Any) -> dict[str, int]:
        sec, nsec = divmod(int(d.nanoseconds), 1_000_000_000)
        return {"sec": sec, "nsec": nsec}

    return {
        "history": qos.history.name.lower(),
        "depth": int(qos.depth),
        "reliability": qos.reliability.name.lower(),
        "durability": qos.durability.name.lower(),
        "deadline": duration(qos.deadline),
        "lifespan": duration(qos.lifespan),
        "liveliness": qos.liveliness.name.lower(),
        "liveliness_lease_duration": duration(qos.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": bool(qos.avoid_ros_namespace_conventions),
    }


def _message_class(type_name: str) -> type:
    pkg, _, name = type_name.partition("/msg/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def type_name_of(msg_type: type) -> str:
    """``pkg/msg/Type`` of a message class."""
    return f"{msg_type.__module__.partition('.')[0]}/msg/{msg_type.__name__}"


class Recorder(Node):
    """Records all discovered topics (see module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("recorder", **node_kwargs)
        declare_parameters(self, PARAMETERS, LIMITS)
        p = self.get_parameter
        self._include = re.compile(p("include").value)
        self._exclude = set(p("exclude").value)
        policy = RecordingPolicy(
            max_file_bytes=int(float(p("max_file_mb").value) * 1024 * 1024),
            max_file_duration_s=float(p("max_file_duration_s").value),
            chunk_bytes=int(p("chunk_kb").value) * 1024,
            flush_period_s=float(p("flush_period_s").value),
            compression=p("compression").value,
        )
        self._output_dir = p("output_dir").value
        self._metadata = {
            "vehicle": p("vehicle").value,
            "software_version": _software_version(),
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "model_ids": p("model_ids").value,
            # Present from the start: the writer thread reads the dict while this one updates.
            "thruster_ids": "",
        }
        prefix = p("prefix").value or time.strftime("%Y%m%d_%H%M%S")
        self._writer = BagWriter(self._output_dir, prefix, policy, self._metadata)
        self._error_logged = ""
        self._subscribed: dict[str, str] = {}
        # topic -> its subscription, and the topics whose subscription has matched a publisher.
        self._recorded_subs: dict[str, Any] = {}
        self._matched: tuple[str, ...] = ()
        # topic -> (type, offered QoS profiles, type hash), for every bag this node opens.
        self._topics: dict[str, tuple[str, list[dict[str, Any]], str]] = {}
        # Topics handed over by nodes of this process (``record``), with their type names.
        self._local: dict[str, str] = {}
        self._thrusters: set[str] = set()
        # Topics with a message written (their publishers' QoS was looked up before the first).
        self._written: set[str] = set()
        self._received = 0
        self._window = (0, time.monotonic())
        self._diag_pub = diagnostics_publisher(self)
        self.create_timer(float(p("discovery_period_s").value), self._discover)
        # The first discovery comes with the first period, after a container's ``take_local``.
        self.create_timer(float(p("diagnostics_period_s").value), self._publish_diagnostics)

    def take_local(self, topics: Iterable[str]) -> None:
        """Record ``topics`` (fully qualified) from ``record`` calls of nodes in this process
        instead of subscribing to them over DDS."""
        for topic in topics:
            self._local.setdefault(topic, "")
            self._subscribed[topic] = ""
            sub = self._recorded_subs.pop(topic, None)
            if sub is not None:
                self.destroy_subscription(sub)
            self._note_thruster(topic)
        self._publish_diagnostics(periodic=False)

    def record(self, topic: str, msg_type: type, data: bytes) -> None:
        """Record one CDR message a node of this process published or took (any thread).

        The topic's publishers' QoS and type hash are looked up with its first message.
        """
        type_name = self._local.get(topic)
        if not type_name:
            type_name = self._local[topic] = type_name_of(msg_type)
            self._subscribed[topic] = type_name
            self._declare(topic, type_name)
            self._written.add(topic)
        self._received += 1
        self._writer.write(topic, type_name, data, time.time_ns())

    def _declare(self, topic: str, type_name: str) -> None:
        offered, type_hash = self._offered(topic)
        self._topics[topic] = (type_name, offered, type_hash)
        self._writer.add_topic(topic, type_name, offered, type_hash)

    def _note_thruster(self, topic: str) -> None:
        match = _THRUSTER_TOPIC.match(topic)
        if match:
            self._thrusters.add(match[1])
            self._metadata["thruster_ids"] = ",".join(sorted(self._thrusters))

    def _offered(self, topic: str) -> tuple[list[dict[str, Any]], str]:
        """The QoS profiles and the type hash the publishers of ``topic`` offer now (``[]``
        and ``""`` while it has none)."""
        publishers = self.get_publishers_info_by_topic(topic)
        offered = [qos_profile_dict(info.qos_profile) for info in publishers]
        type_hash = str(getattr(publishers[0], "topic_type_hash", "")) if publishers else ""
        return offered, type_hash

    def _adapt(self, topic: str) -> bool:
        """Take the publishers' QoS and type hash of a topic recorded without them yet; True
        when the topic has them (now or before)."""
        type_name, offered, type_hash = self._topics[topic]
        if offered:
            return True
        offered, type_hash = self._offered(topic)
        if not offered:
            return False
        self._topics[topic] = (type_name, offered, type_hash)
        self._writer.add_topic(topic, type_name, offered, type_hash)
        self.get_logger().info(f"{topic}: publishers appeared, their QoS is recorded")
        return True

    def _matched_topics(self) -> tuple[str, ...]:
        """The recorded topics whose subscription has matched at least one publisher, and the
        topics of this process's nodes (recorded from their first message on)."""
        remote = (t for t, sub in self._recorded_subs.items() if sub.get_publisher_count() > 0)
        return tuple(sorted({*remote, *self._local}))

    def _discover(self) -> None:
        for topic in list(self._topics):
            self._adapt(topic)
        matched = self._matched_topics()
        if matched != self._matched:
            # At once, not at the next period: ``up`` activates the drivers when it sees its
            # telemetry topics here, so that no sample is published before it is recorded.
            self._matched = matched
            self._publish_diagnostics(periodic=False)
        for topic, types in self.get_topic_names_and_types():
            if topic in self._subscribed or not types:
                continue
            if not self._include.search(topic) or topic in self._exclude:
                continue
            type_name = types[0]
            try:
                msg_class = _message_class(type_name)
            except (ImportError, AttributeError):
                self.get_logger().warning(f"cannot record {topic}: type {type_name} not found")
                self._subscribed[topic] = type_name
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            self._declare(topic, type_name)
            reliable = bool(publishers) and all(
                info.qos_profile.reliability == ReliabilityPolicy.RELIABLE for info in publishers
            )
            latched = bool(publishers) and all(
                info.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                for info in publishers
            )
            qos = QoSProfile(
                depth=_LATCHED_DEPTH if latched else 200,
                reliability=ReliabilityPolicy.RELIABLE
                if reliable
                else ReliabilityPolicy.BEST_EFFORT,
                durability=DurabilityPolicy.TRANSIENT_LOCAL
                if latched
                else DurabilityPolicy.VOLATILE,
            )
            self._recorded_subs[topic] = self.create_subscription(
                msg_class,
                topic,
                lambda data, topic=topic, type_name=type_name: self._on_message(
                    topic, type_name, data
                ),
                qos,
                raw=True,
            )
            self._subscribed[topic] = type_name
            self._note_thruster(topic)
            self.get_logger().info(f"recording {topic} [{type_name}]")

    def _on_message(self, topic: str, type_name: str, data: bytes) -> None:
        self._received += 1
        if topic not in self._written:
            # The file's channel is made with the first message: by then a publisher exists.
            self._adapt(topic)
            self._written.add(topic)
        self._writer.write(topic, type_name, data, time.time_ns())

    def _publish_diagnostics(self, periodic: bool = True) -> None:
        """The recorder's status; ``periodic`` False for an extra one between two periods (a
        change of the matched topics): it does not count as the status that reported an
        error (a subscriber may not have matched it yet)."""
        received, since = self._window
        now = time.monotonic()
        rate = (self._received - received) / max(now - since, 1e-9)
        if periodic:
            self._window = (self._received, now)
        status = self._writer.status(report=periodic)
        if status.error:
            level, message = DiagnosticStatus.ERROR, status.error
            if status.error != self._error_logged:
                self.get_logger().error(status.error)
            self._error_logged = status.error
        else:
            level, message = DiagnosticStatus.OK, f"recording {len(self._subscribed)} topics"
            self._error_logged = ""
        publish_status(
            self,
            self._diag_pub,
            level,
            status_name("recorder"),
            message,
            self._metadata["vehicle"],
            [
                ("output_dir", str(self._output_dir)),
                ("messages_per_s", f"{rate:.1f}"),
                ("topics", str(len(self._subscribed))),
                ("dropped", str(status.dropped)),
                ("bag", status.bag_dir),
                ("files", ",".join(status.files)),
                ("matched", ",".join(self._matched_topics())),
            ],
        )

    def shutdown(self) -> None:
        """Write what is queued and finish the current file with a complete summary."""
        self._writer.close()
        error = self._writer.status().error
        if error:
            self.get_logger().error(error)


def main(args: list[str] | None = None) -> None:
    """Run the recorder until Ctrl-C; the last file is finished cleanly."""
    run(Recorder, args)


if __name__ == "__main__":
    main()
