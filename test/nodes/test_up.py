"""`thruster-fdd up` end to end: emulators, drivers, command players, the live table, shutdown."""

from __future__ import annotations

import re
import subprocess
import time
from pathlib import Path

import pytest

from thruster_fdd.core.artifact import default_models_dir

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def _children_of(pid: int) -> list[int]:
    out = subprocess.run(["ps", "-eo", "pid,ppid"], capture_output=True, text=True).stdout
    return [int(p) for p, pp in (line.split() for line in out.splitlines()[1:]) if int(pp) == pid]


def test_up_runs_two_simulated_thrusters_and_stops_cleanly(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    from thruster_fdd.core.traces.files import bag_files
    from thruster_fdd.core.traces.mcap_io import read_trace_mcap

    cmd = ["thruster-fdd", "up", "--thrusters", "2", "--duration", "12", "--print-period", "2"]
    proc = subprocess.Popen(
        [*cmd, "--record-dir", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    stages = sum(
        (default_models_dir() / folder / "model_card.json").is_file()
        for folder in ("nominal", "classifier")
    )
    # An emulator, a driver and a command player per thruster; a recorder; the health node;
    # one container for the exported model stages.
    expected = 2 * 3 + 2 + (stages > 0)
    deadline = time.monotonic() + 10.0  # a loaded machine starts them in seconds
    children = _children_of(proc.pid)
    while len(children) < expected and time.monotonic() < deadline:
        time.sleep(0.2)
        children = _children_of(proc.pid)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out
    assert len(children) == expected
    final = out.split("final:")[1]
    rows = {m[1]: float(m[2]) for m in re.finditer(r"^(t\d)\s+([\d.]+)\s", final, re.M)}
    assert set(rows) == {"t0", "t1"}
    assert all(40.0 <= rate <= 60.0 for rate in rows.values()), final
    assert final.count("OK: telemetry") == 2, final
    time.sleep(0.5)
    for pid in children:
        stat = Path(f"/proc/{pid}/stat")
        assert not stat.exists() or " Z " in stat.read_text(), f"child {pid} still running"
    (bag,) = tmp_path.glob("up_*")
    files = bag_files(bag)
    assert files, out
    traces = {t.thruster_id: t for t in read_trace_mcap(files[0])}
    with files[0].open("rb") as f:
        records = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    meta = records["thruster_fdd_final"]
    assert meta["thruster_ids"] == "t0,t1"
    assert int(meta["messages"]) > 0
    if stages:
        assert meta["model_ids"].startswith("nominal=nominal-")
    assert set(traces) == {"t0", "t1"}
    assert len(traces["t0"]) > 4 * 40, "at least 4 s of 50 Hz telemetry recorded"


def test_up_rejects_a_bad_fault_spec() -> None:
    out = subprocess.run(
        ["thruster-fdd", "up", "--fault", "t9:biofouling@3", "--duration", "1"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert "--fault" in out.stderr


def test_a_live_fault_recorded_by_up_replays_to_the_same_diagnoses(tmp_path: Path) -> None:
    models = default_models_dir()
    if not (models / "classifier" / "model_card.json").is_file():
        pytest.fail("the committed classifier model is missing")
    live = subprocess.run(
        ["thruster-fdd", "up", "--duration", "70", "--signal", "multilevel", "--print-period",
         "10", "--fault", "t0:broken_blade_2@25", "--record-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=240,
    )  # fmt: skip
    assert live.returncode == 0, live.stdout[-3000:]
    (bag,) = tmp_path.glob("up_*")  # the bag folder
    replay = subprocess.run(
        ["thruster-fdd", "replay", str(bag), "--json", str(tmp_path / "r.json")],
        capture_output=True,
        text=True,
        timeout=240,
    )
    print(replay.stdout)
    assert "expected (recorded)" in replay.stdout
    assert replay.returncode == 0, replay.stdout + replay.stderr[-2000:]


def test_kill_9_of_up_still_finishes_the_bag(tmp_path: Path) -> None:
    """The recorder gets SIGINT when `up` dies (PR_SET_PDEATHSIG) and writes the files' ends:
    the bag opens in rosbags' reader, which needs every file complete."""
    import os
    import signal

    from rosbags.rosbag2 import Reader

    proc = subprocess.Popen(
        ["thruster-fdd", "up", "--duration", "120", "--print-period", "30", "--record-dir",
         str(tmp_path)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and not list(tmp_path.glob("up_*/metadata.yaml")):
            time.sleep(0.5)
        time.sleep(6.0)  # telemetry, residuals and health to record
        children = _children_of(proc.pid)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        end = time.monotonic() + 20.0
        while time.monotonic() < end and any(
            Path(f"/proc/{pid}").exists() and " Z " not in Path(f"/proc/{pid}/stat").read_text()
            for pid in children
        ):
            time.sleep(0.2)
    finally:
        if proc.poll() is None:
            proc.kill()
    (bag,) = tmp_path.glob("up_*")
    with Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert sum(1 for _ in reader.messages()) == reader.message_count
    assert counts["/thruster/t0/esc/telemetry"] > 100
    assert counts.get("/thruster_fdd/health", 0) >= 1
