"""Replay of the committed bags through the real model nodes: correct, deterministic, = offline."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from mcap.reader import make_reader

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd_shore.core.diagnosis.offline import diagnose_trace
from thruster_fdd_shore.core.traces.files import read_traces

pytestmark = [pytest.mark.ros, pytest.mark.slow]

BAGS = Path(__file__).resolve().parents[3] / "bags"
MODELS = default_models_dir()


def _replay(bag: Path, out: Path) -> tuple[int, dict]:
    proc = subprocess.run(
        ["thruster-fdd", "replay", str(bag), "--json", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.is_file(), proc.stderr[-2000:]
    return proc.returncode, json.loads(out.read_text())


def test_the_bags_are_there() -> None:
    names = {p.stem for p in BAGS.glob("*.mcap")}
    assert {"nominal_15v", "nominal_13v", "nominal_11v8", "broken_blade_1", "broken_blade_2",
            "biofouling"} <= names  # fmt: skip
    assert any(n.startswith("fault_") for n in names)


@pytest.mark.parametrize("bag", sorted(BAGS.glob("*.mcap")), ids=lambda p: p.stem)
def test_each_bag_replays_to_its_ground_truth(bag: Path, tmp_path: Path) -> None:
    code, result = _replay(bag, tmp_path / "r.json")
    (thruster,) = result["thrusters"]
    assert thruster["source"] == "truth"
    assert result["timeouts"] == 0
    assert result["classifier_stalls"] == 0
    assert thruster["sequence"] == thruster["expected_sequence"], thruster["sequence"]
    assert thruster["agreement"] >= 0.9
    assert code == 0


def test_replay_is_deterministic_and_equals_offline_diagnosis(tmp_path: Path) -> None:
    (bag,) = BAGS.glob("fault_*.mcap")
    _, first = _replay(bag, tmp_path / "a.json")
    _, second = _replay(bag, tmp_path / "b.json")
    online = [(round(t, 3), label) for t, label in first["thrusters"][0]["diagnoses"]]
    assert online == [(round(t, 3), label) for t, label in second["thrusters"][0]["diagnoses"]]
    offline = diagnose_trace(read_traces([bag])[0], MODELS / "nominal", MODELS / "classifier")
    # A simulated bag's stamps are its time origin plus the trace's times (docs/contracts.md).
    with bag.open("rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    origin = int(meta["thruster_fdd"].get("time_origin_ns", 0)) * 1e-9
    assert online == [(round(origin + w["t_end"], 3), w["label"]) for w in offline["windows"]]
    assert len(online) > 100
    print(f"replay speed {first['speedup']:.0f}x real time")
