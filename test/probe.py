"""What the node tests share: the probe (``thruster_fdd_shore.nodes.probe``) and the node processes
under test (stopped with ``thruster_fdd.lifetime.stop_children``, as ``up`` and ``replay`` stop
theirs), and the replay check of a bag a live run recorded.

Each test graph runs the node under test as a process from its entry module (as ``thruster-fdd
up`` starts it) and talks to it from a probe node in the test process, on a private rclpy
context spun by a single-threaded executor in the test's thread.
"""

from __future__ import annotations

import json
import math
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from thruster_fdd.lifetime import node_command
from thruster_fdd_shore.nodes.probe import Probe

__all__ = [
    "DriverWatch",
    "Probe",
    "non_finite_fields",
    "replay_and_diagnose",
    "start_node",
    "watch_driver",
]


def start_node(
    module: str, namespace: str | None = None, params: Mapping[str, object] | None = None
) -> subprocess.Popen[bytes]:
    """Start ``thruster_fdd.nodes.<module>`` in ``namespace`` with parameter overrides, as ``up``
    builds its command line (``lifetime.node_command``)."""
    return subprocess.Popen(node_command(module, namespace, params))


def non_finite_fields(msg: Any, prefix: str = "") -> list[str]:
    """Names of the float fields of a ROS message (nested, sequences included) that are not
    finite."""
    bad = []
    for name, kind in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        if kind in ("double", "float"):
            if not math.isfinite(value):
                bad.append(prefix + name)
        elif kind.startswith("sequence<double") or kind.startswith("sequence<float"):
            bad += [f"{prefix}{name}[{i}]" for i, v in enumerate(value) if not math.isfinite(v)]
        elif hasattr(value, "get_fields_and_field_types"):
            bad += non_finite_fields(value, f"{prefix}{name}.")
    return bad


@dataclass
class DriverWatch:
    """A probe's side of one ESC driver: its command publisher and what the driver published
    (lists the probe's subscriptions append to)."""

    command_pub: Any
    telemetry: list = field(default_factory=list)
    diagnostics: list = field(default_factory=list)


def watch_driver(probe: Probe, namespace: str, thruster_id: str) -> DriverWatch:
    """Publish commands to the driver in ``namespace`` and collect its telemetry and its own
    ``/diagnostics`` status (``thruster_fdd: esc <thruster_id>``)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from thruster_fdd_msgs.msg import EscTelemetry, ThrusterCommand

    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    node = probe.node
    watch = DriverWatch(
        node.create_publisher(ThrusterCommand, f"{namespace}/esc/command", reliable)
    )
    node.create_subscription(
        EscTelemetry, f"{namespace}/esc/telemetry", watch.telemetry.append, qos_profile_sensor_data
    )
    name = f"thruster_fdd: esc {thruster_id}"
    node.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda msg: watch.diagnostics.extend(s for s in msg.status if s.name == name),
        reliable,
    )
    return watch


def replay_and_diagnose(bag: Path, out: Path) -> tuple[subprocess.CompletedProcess, dict, dict]:
    """``thruster-fdd replay`` and ``diagnose`` of a recorded bag: the replay's process, its JSON
    and the ``diagnose`` JSON."""
    replay = subprocess.run(
        ["thruster-fdd", "replay", str(bag), "--json", str(out / "r.json")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    print(replay.stdout, replay.stderr[-2000:])
    assert (out / "r.json").is_file(), replay.stderr[-2000:]
    offline = subprocess.run(
        ["thruster-fdd", "diagnose", str(bag), "--json", str(out / "d.json")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    print(offline.stderr[-2000:])
    assert offline.returncode == 0, offline.stderr[-2000:]
    return (
        replay,
        json.loads((out / "r.json").read_text()),
        json.loads((out / "d.json").read_text()),
    )
