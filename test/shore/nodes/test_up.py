"""`thruster-fdd up` end to end: emulators, drivers, command players, the live table, shutdown."""

from __future__ import annotations

import json
import os
import re
import signal
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

    from thruster_fdd.core.traces.mcap_io import read_trace_mcap
    from thruster_fdd_shore.core.traces.files import bag_files

    cmd = ["thruster-fdd", "up", "--thrusters", "2", "--duration", "12", "--print-period", "2"]
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.Popen(
        [*cmd, "--record-dir", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "TMPDIR": str(tmp)},
    )
    stages = sum(
        (default_models_dir() / folder / "model_card.json").is_file()
        for folder in ("nominal", "classifier")
    )
    # An emulator per thruster; one container with the command players; the vehicle process
    # (drivers, exported model stages, health node and recorder).
    expected = 2 + 2
    deadline = time.monotonic() + 10.0  # a loaded machine starts them in seconds
    children = _children_of(proc.pid)
    while len(children) < expected and time.monotonic() < deadline:
        time.sleep(0.2)
        children = _children_of(proc.pid)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out
    assert "the recorder exited" not in out
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
    assert not list(tmp.glob("thruster_fdd-up-*")), "the run folder is left after a clean run"
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


def _child_running(parent: int, text: str) -> int | None:
    """The pid of ``parent``'s child whose command line holds ``text`` (None if none runs)."""
    for pid in _children_of(parent):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if text in cmdline:
            return pid
    return None


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
    # The same windows as live, decision for decision (``unknown`` included): the bag holds the
    # first samples the live model used (up waits for the recorder), so every decision and its
    # label are compared, and replay and diagnose decide on the samples the live model used.
    (thruster,) = json.loads((tmp_path / "r.json").read_text())["thrusters"]
    assert thruster["agreement"] == 1.0, thruster
    assert thruster["labels_compared"], thruster
    assert thruster["not_comparable"] == {}, thruster
    replayed = [(round(t, 3), label) for t, label in thruster["diagnoses"]]
    offline = subprocess.run(
        ["thruster-fdd", "diagnose", str(bag), "--json", str(tmp_path / "d.json")],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert offline.returncode == 0, offline.stderr[-2000:]
    windows = json.loads((tmp_path / "d.json").read_text())["windows"]
    assert replayed == [(round(w["t_end"], 3), w["label"]) for w in windows]


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


def test_per_thruster_driver_settings_reach_the_parameters_file(tmp_path: Path) -> None:
    import argparse

    import yaml

    from thruster_fdd.core.errors import BadInputError
    from thruster_fdd_shore.commands.up import node_parameters, plan_from_args, write_parameters

    config = tmp_path / "up.yaml"
    config.write_text(
        "rate_hz: 50\nthrusters:\n"
        "  - {id: t0}\n"
        "  - {id: t1, port: /dev/ttyUSB1, protocol: kiss, baud: 57600, pole_pairs: 14,\n"
        "     rate_hz: 100, command_rate_hz: 25, command_timeout_s: 0.3,\n"
        "     max_command_rate_per_s: 0, bridge_timeout_ms: 250}\n"
    )
    args = argparse.Namespace(config=config, rate=50.0, fault=[], bridge="python")
    rate, plans = plan_from_args(args)
    params = node_parameters(plans, rate, tmp_path, tmp_path / "no-models")
    write_parameters(params, tmp_path / "params.yaml")
    written = yaml.safe_load((tmp_path / "params.yaml").read_text())
    t1 = written["/thruster/t1/esc_driver"]["ros__parameters"]
    assert t1 == {
        "thruster_id": "t1",
        "port": "/dev/ttyUSB1",
        "protocol": "kiss",
        "rate_hz": 100.0,
        "baud": 57600,
        "pole_pairs": 14,
        "command_rate_hz": 25,
        "command_timeout_s": 0.3,
        "max_command_rate_per_s": 0,
        "bridge_timeout_ms": 250,
    }
    t0 = written["/thruster/t0/esc_driver"]["ros__parameters"]
    assert t0 == {
        "thruster_id": "t0",
        "port": str(tmp_path / "t0.tty"),
        "protocol": "tfdd",
        "rate_hz": 50.0,
    }
    assert "/thruster/t0/command_player" in written
    assert "/thruster/t1/command_player" not in written
    config.write_text("thrusters:\n  - {id: t0, port: /dev/ttyS0}\n  - {id: t1, port: /dev/ttyS0}")
    with pytest.raises(BadInputError, match="same serial device"):
        plan_from_args(args)
    for bad in ("baud: -1", "baud: 9600.5", "command_timeout_s: 0", "pole_pairs: true"):
        config.write_text(f"thrusters:\n  - {{id: t0, {bad}}}\n")
        with pytest.raises(BadInputError, match=bad.split(":")[0]):
            plan_from_args(args)


def _vehicle_of(proc: subprocess.Popen[str], timeout_s: float) -> int:
    """The pid of ``up``'s vehicle process, waited for up to ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        vehicle = _child_running(proc.pid, "thruster_fdd.nodes.container esc_driver")
        if vehicle is not None:
            return vehicle
        time.sleep(0.05)
    raise AssertionError("up started no vehicle process")


@pytest.mark.parametrize(
    ("vehicle_signal", "code", "said"),
    [
        (signal.SIGSTOP, 0, "stopped before the drivers were active"),
        (signal.SIGKILL, 1, "vehicle exited before the drivers were active"),
    ],
    ids=["ctrl-c-while-the-vehicle-hangs", "the-vehicle-dies"],
)
def test_up_stops_waiting_for_the_drivers_at_once(
    tmp_path: Path, vehicle_signal: int, code: int, said: str
) -> None:
    """While ``up`` waits for the drivers' lifecycle services (up to 60 s), a Ctrl-C or the
    vehicle process' death ends the wait at once: ``up`` is gone within the 5 s it gives its
    children to stop, not after the lifecycle timeout."""
    proc = subprocess.Popen(
        ["thruster-fdd", "up", "--duration", "120", "--no-record"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    vehicle = None
    try:
        vehicle = _vehicle_of(proc, 30.0)
        os.kill(vehicle, vehicle_signal)  # before it loaded its models and made its services
        time.sleep(1.0)
        start = time.monotonic()
        if vehicle_signal == signal.SIGSTOP:
            proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
        elapsed = time.monotonic() - start
    finally:
        proc.kill()
        if vehicle is not None and Path(f"/proc/{vehicle}").exists():
            os.kill(vehicle, signal.SIGKILL)
    assert proc.returncode == code, out
    assert said in out, out
    assert elapsed < 12.0, f"up took {elapsed:.1f} s to stop"
    assert "running for" not in out


def test_a_second_up_on_the_domain_refuses_and_leaves_the_first_alone(tmp_path: Path) -> None:
    from probe import Probe

    from thruster_fdd_shore.nodes.lifecycle_client import get_state

    first = subprocess.Popen(
        ["thruster-fdd", "up", "--duration", "60", "--print-period", "5", "--record-dir",
         str(tmp_path / "first")],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )  # fmt: skip
    try:
        with Probe("second_up_probe") as probe:
            deadline = time.monotonic() + 90.0
            state = None
            while state != "active" and time.monotonic() < deadline:
                state = get_state(probe.node, probe.executor, "/thruster/t0/esc_driver", 5.0)
            assert state == "active", "the first up never activated its driver"
            second = subprocess.run(
                ["thruster-fdd", "up", "--duration", "5", "--record-dir", str(tmp_path / "second")],
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert second.returncode == 2, second.stdout + second.stderr
            assert len(second.stderr.strip().splitlines()) == 1, second.stderr
            assert "already has /" in second.stderr  # the names first discovered
            assert not (tmp_path / "second").exists(), "the second up started its recorder"
            probe.spin(2.0)
            state = get_state(probe.node, probe.executor, "/thruster/t0/esc_driver", 10.0)
            assert state == "active", "the second up changed the first one's driver"
        first.send_signal(signal.SIGINT)
        out, _ = first.communicate(timeout=60)
    finally:
        first.kill()
    assert first.returncode == 0, out
    assert "OK: telemetry" in out.split("final:")[1], out


def test_up_refuses_a_domain_where_a_driver_of_its_names_runs(tmp_path: Path) -> None:
    """A node of a name ``up`` would start (here a driver, as the launch file starts it) is
    found before anything starts: one line, exit 2, and the node is left as it was."""
    from probe import Probe, start_node

    from thruster_fdd.lifetime import stop_children
    from thruster_fdd_shore.nodes.lifecycle_client import get_state

    driver = start_node("esc_driver", "/thruster/t0", {"port": str(tmp_path / "none.tty")})
    try:
        with Probe("driver_name_probe") as probe:
            state = get_state(probe.node, probe.executor, "/thruster/t0/esc_driver", 30.0)
            assert state == "unconfigured"
            up = subprocess.run(
                ["thruster-fdd", "up", "--duration", "5", "--no-record"],
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert up.returncode == 2, up.stdout + up.stderr
            assert len(up.stderr.strip().splitlines()) == 1, up.stderr
            assert "/thruster/t0/esc_driver" in up.stderr
            state = get_state(probe.node, probe.executor, "/thruster/t0/esc_driver", 10.0)
            assert state == "unconfigured", "up changed a driver it did not start"
    finally:
        stop_children({"driver": driver}, timeout_s=10.0)
