"""The files in config/: the diagnostic_aggregator analyzers group every status the nodes
publish, and the Foxglove layout's panels read topics and fields that exist."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

CONFIG = Path(__file__).resolve().parents[1] / "src" / "thruster_fdd" / "config"
NODES = Path(__file__).resolve().parents[1] / "src" / "thruster_fdd" / "thruster_fdd" / "nodes"


def _tasks() -> tuple[set[str], set[str]]:
    """Status tasks of the nodes, per thruster and vehicle-wide, read from their code."""
    per_thruster, vehicle = set(), set()
    for path in NODES.glob("*.py"):
        for task, arg in re.findall(r'status_name\("(\w+)"(, *[\w.]+)?\)', path.read_text()):
            (per_thruster if arg else vehicle).add(task)
    return per_thruster, vehicle


def _leaves(analyzers: dict, path: str = "") -> list[tuple[str, dict]]:
    out = []
    for spec in analyzers.values():
        if not isinstance(spec, dict) or "type" not in spec:
            continue
        if spec["type"] == "diagnostic_aggregator/AnalyzerGroup":
            out += _leaves(spec["analyzers"], f"{path}/{spec['path']}")
        else:
            out.append((f"{path}/{spec['path']}", spec))
    return out


def _matches(spec: dict, name: str) -> bool:
    """diagnostic_aggregator GenericAnalyzer's match (regex_match, exact, prefix, substring)."""
    return (
        any(re.fullmatch(r, name) for r in spec.get("regex", []))
        or name in spec.get("expected", [])
        or name in spec.get("name", [])
        or any(name.startswith(s) for s in spec.get("startswith", []))
        or any(c in name for c in spec.get("contains", []))
    )


def test_aggregator_groups_every_status_once() -> None:
    from thruster_fdd.nodes.common import status_name

    per_thruster, vehicle = _tasks()
    assert {"esc", "nominal_model", "classifier"} <= per_thruster
    assert {"recorder", "health"} <= vehicle
    spec = yaml.safe_load((CONFIG / "diagnostic_aggregator.yaml").read_text())
    leaves = _leaves(spec["analyzers"]["ros__parameters"])
    names = [status_name(task, tid) for task in per_thruster for tid in ("t0", "t3", "t7")]
    names += [status_name(task) for task in vehicle]
    for name in names:
        where = [path for path, leaf in leaves if _matches(leaf, name)]
        assert len(where) == 1, f"{name!r} grouped under {where}"
        if name.endswith(" t0"):
            assert where == ["/Thrusters/t0"]
    # Every expected item is a name some node publishes.
    published = {status_name(t, i) for t in per_thruster for i in ("t0", "t1", "t2", "t3")}
    published |= {status_name(t) for t in vehicle}
    for _, leaf in leaves:
        assert set(leaf.get("expected", [])) <= published


def _fields(type_name: str) -> dict[str, str]:
    import importlib

    pkg, _, name = type_name.partition("/")
    cls = getattr(importlib.import_module(f"{pkg}.msg"), name)
    return cls.get_fields_and_field_types()


TOPIC_TYPES = {
    r"(/studio_script)?/thruster/(\w+/)?esc/telemetry": "thruster_fdd_msgs/EscTelemetry",
    r"(/studio_script)?/thruster/(\w+/)?fdd/residual": "thruster_fdd_msgs/Residual",
    r"(/studio_script)?/thruster/(\w+/)?fdd/diagnosis": "thruster_fdd_msgs/Diagnosis",
    r"/thruster_fdd/health": "thruster_fdd_msgs/VehicleHealth",
    r"/diagnostics": "diagnostic_msgs/DiagnosticArray",
}


def _resolve(path: str) -> None:
    """Fail unless a Foxglove message path names a topic of ours and fields of its type."""
    topic, _, rest = path.partition(".")
    topic, _, _ = topic.partition("{")  # a filter on the message itself: /topic{field==x}.y
    types = [t for pattern, t in TOPIC_TYPES.items() if re.fullmatch(pattern, topic)]
    assert types, f"{path}: unknown topic"
    type_name = types[0]
    for part in filter(None, rest.split(".")):
        field = re.sub(r"\[.*?\]|\{.*?\}", "", part)
        fields = _fields(type_name)
        assert field in fields, f"{path}: {type_name} has no field {field!r}"
        kind = fields[field]
        inner = re.sub(r"^sequence<(.+)>$", r"\1", kind)
        if "/" in inner:
            type_name = inner
        if "{" in part:  # a filter names fields of the element type
            for key in re.findall(r"\{(\w+)==", part):
                assert key in _fields(type_name), f"{path}: filter on unknown field {key!r}"


@pytest.mark.ros
def test_foxglove_layout_panels_read_existing_topics_and_fields() -> None:
    doc = json.loads((CONFIG / "foxglove_layout.json").read_text())
    configs = doc["configById"]

    def panels(node: object) -> list[str]:
        if isinstance(node, str):
            return [node]
        assert isinstance(node, dict)
        assert node["direction"] in ("row", "column")
        return panels(node["first"]) + panels(node["second"])

    assert sorted(panels(doc["layout"])) == sorted(configs)
    kinds = {key.split("!")[0] for key in configs}
    assert {"Plot", "StateTransitions", "RawMessages", "DiagnosticSummary"} <= kinds
    paths = [p["value"] for c in configs.values() for p in c.get("paths", [])]
    paths += [c["topicPath"] for c in configs.values() if "topicPath" in c]
    paths += [c["topicToRender"] for c in configs.values() if "topicToRender" in c]
    for topic in ("/esc/telemetry", "/fdd/residual", "/fdd/diagnosis", "/thruster_fdd/health"):
        assert any(topic in p for p in paths), f"no panel shows {topic}"
    for path in paths:
        _resolve(path)
