"""Replay of the committed bags through the real model nodes: correct, deterministic, = offline."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from mcap.reader import make_reader
from probe import replay_and_diagnose

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


def test_a_recording_started_while_the_vehicle_runs_replays_to_the_live_windows(
    tmp_path: Path,
) -> None:
    """``thruster-fdd record`` started after the vehicle: the bag begins mid-stream. Every live
    decision whose window and model history lie in the bag is reproduced exactly by replay and
    by diagnose; the leading ones are counted as not comparable, and so are the labels, whose
    evidence began before the recording."""
    import signal
    import time

    up = subprocess.Popen(
        ["thruster-fdd", "up", "--no-record", "--duration", "58", "--signal", "multilevel",
         "--print-period", "2", "--fault", "t0:broken_blade_2@25"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )  # fmt: skip
    record = None
    try:
        assert up.stdout is not None
        deadline = time.monotonic() + 60.0
        for line in up.stdout:  # the first table: the vehicle runs
            if line.startswith("[t =") or time.monotonic() > deadline:
                break
        time.sleep(4.0)
        record = subprocess.Popen(
            ["thruster-fdd", "record", "--out", str(tmp_path / "rec")],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(38.0)
        record.send_signal(signal.SIGINT)
        assert record.wait(timeout=30) == 0
        rest, _ = up.communicate(timeout=60)
        assert up.returncode == 0, rest[-3000:]
    finally:
        for proc in (record, up):
            if proc is not None and proc.poll() is None:
                proc.kill()
    (bag,) = (tmp_path / "rec").iterdir()
    replay, result, offline = replay_and_diagnose(bag, tmp_path)
    (thruster,) = result["thrusters"]
    assert thruster["source"] == "recorded"
    assert thruster["agreement"] == 1.0, thruster
    assert thruster["not_comparable"].get("before_recording", 0) > 0, thruster
    assert not thruster["labels_compared"]
    assert thruster["compared"] >= 10, thruster
    assert replay.returncode == 0, replay.stdout
    replayed = [round(t, 3) for t, _ in thruster["diagnoses"]]
    assert replayed == [round(w["t_end"], 3) for w in offline["windows"]]
    assert offline.get("not_comparable", {}) == thruster["not_comparable"]
