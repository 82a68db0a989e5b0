"""The launch file run by the real ROS launch system: N thrusters from one parameters file.

``launch`` and ``launch_ros`` have no wheels; ``scripts/bootstrap.sh`` builds them from
``../shared/vendor/ros2-launch-jazzy`` when that folder exists, and this test is skipped where it
does not. The launch service runs in a child process (it installs signal handlers); two
emulated bridges serve the thrusters' ports from this process; a probe checks the topics, and
``replay`` and ``diagnose`` check the bag the launch file's recorder writes.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
from probe import Probe, replay_and_diagnose

from thruster_fdd_shore.core.bridge.emulator import BridgeEmulator, EmulatorSettings
from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator

pytestmark = [pytest.mark.ros, pytest.mark.slow]

CONTRACTS = Path(__file__).resolve().parents[3] / "docs" / "contracts.md"

NOT_BUILT = (
    "the ROS launch system is built from ../shared/vendor/ros2-launch-jazzy by "
    "scripts/bootstrap.sh, which is absent here"
)

# LaunchService.run() returns 0 even when a process fails, so every exit is printed.
RUNNER = """
import sys
from launch import LaunchDescription, LaunchService
from launch.actions import IncludeLaunchDescription, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.launch_description_sources import PythonLaunchDescriptionSource

def report(event, context):
    print(f"exit {event.action.name} {event.returncode}", flush=True)

service = LaunchService()
service.include_launch_description(LaunchDescription([
    RegisterEventHandler(OnProcessExit(on_exit=report)),
    IncludeLaunchDescription(
        PythonLaunchDescriptionSource(sys.argv[1]),
        launch_arguments={"params_file": sys.argv[2]}.items(),
    ),
]))
sys.exit(service.run())
"""


def contract_topics(thruster_ids: tuple[str, ...]) -> set[str]:
    """Every topic of docs/contracts.md's topic tables, per-thruster ones for each id."""
    text = CONTRACTS.read_text().split("## Topics", 1)[1].split("\n## ", 1)[0]
    topics = set()
    for name in re.findall(r"^\| `([^`]+)` \|", text, flags=re.MULTILINE):
        if name.startswith("/"):
            topics.add(name)
        else:
            topics |= {f"/thruster/{tid}/{name}" for tid in thruster_ids}
    return topics


def contract_statuses(thruster_ids: tuple[str, ...]) -> set[str]:
    """Every ``/diagnostics`` status name of docs/contracts.md, ``<id>`` for each id."""
    names = set()
    for name in re.findall(r"`(thruster_fdd: [a-z_]+(?: <id>)?)`", CONTRACTS.read_text()):
        if name.endswith(" <id>"):
            names |= {name.replace("<id>", tid) for tid in thruster_ids}
        else:
            names.add(name)
    return names


def write_params(
    tmp_path: Path, ids: tuple[str, ...], stop: threading.Event
) -> tuple[Path, list[threading.Thread]]:
    """An emulated bridge per thruster on a pty in ``tmp_path``, served by a daemon thread until
    ``stop`` is set, and the parameters file naming their ports (the recorder writes into
    ``tmp_path/rec``): the file and the threads."""
    threads = []
    params: dict[str, dict] = {
        "/recorder": {"ros__parameters": {"output_dir": str(tmp_path / "rec")}},
    }
    for i, tid in enumerate(ids):
        emulator = BridgeEmulator(
            ThrusterSimulator(load_config("t100"), "nominal_15v", seed=i),
            tmp_path / f"{tid}.tty",
            EmulatorSettings(rate_hz=50.0),
        )
        emulator.open()
        threads.append(threading.Thread(target=emulator.run, args=(stop,), daemon=True))
        threads[-1].start()
        params[f"/thruster/{tid}/esc_driver"] = {
            "ros__parameters": {"thruster_id": tid, "port": str(tmp_path / f"{tid}.tty")}
        }
    params_file = tmp_path / "params.yaml"
    params_file.write_text(yaml.safe_dump(params))
    return params_file, threads


def start_launch(params_file: Path) -> subprocess.Popen[str]:
    """The package's launch file with ``params_file``, run by the launch system in a child."""
    from ament_index_python.packages import get_package_share_directory

    launch_file = Path(get_package_share_directory("thruster_fdd")) / "launch"
    return subprocess.Popen(
        [sys.executable, "-c", RUNNER, str(launch_file / "thruster_fdd.launch.py"),
         str(params_file)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )  # fmt: skip


def stop_launch(
    launch: subprocess.Popen[str], stop: threading.Event, threads: list[threading.Thread]
) -> str:
    """Ctrl-C to the launch system, then stop the emulators; its output."""
    launch.send_signal(signal.SIGINT)
    try:
        out, _ = launch.communicate(timeout=30)
    finally:
        launch.kill()
        stop.set()
        for thread in threads:
            thread.join(timeout=5)
    return out


def test_the_contract_lists_are_read() -> None:
    topics = contract_topics(("a",))
    assert {"/thruster/a/esc/telemetry", "/thruster_fdd/health", "/diagnostics"} <= topics
    assert len(topics) == 6
    assert contract_statuses(("a",)) == {
        "thruster_fdd: esc a",
        "thruster_fdd: nominal_model a",
        "thruster_fdd: classifier a",
        "thruster_fdd: recorder",
        "thruster_fdd: health",
    }


def test_launch_file_starts_every_thruster_of_its_parameters_file(tmp_path: Path) -> None:
    pytest.importorskip("launch", reason=NOT_BUILT)
    pytest.importorskip("launch_ros", reason=NOT_BUILT)
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import qos_profile_sensor_data
    from thruster_fdd_msgs.msg import EscTelemetry, Residual, VehicleHealth

    from thruster_fdd.nodes.common import RELIABLE_10
    from thruster_fdd.nodes.health import HEALTH_QOS, HEALTH_TOPIC
    from thruster_fdd.nodes.nominal_model import RESIDUAL_QOS

    ids = ("la", "lb")
    stop = threading.Event()
    params_file, threads = write_params(tmp_path, ids, stop)
    launch = start_launch(params_file)
    telemetry: dict[str, list] = {tid: [] for tid in ids}
    residuals: dict[str, list] = {tid: [] for tid in ids}
    health: list = []
    statuses: set[str] = set()
    matched: set[str] = set()
    expected_statuses = contract_statuses(ids)

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for s in msg.status:
            statuses.add(s.name)
            if s.name == "thruster_fdd: recorder":
                matched.update(
                    ",".join(kv.value for kv in s.values if kv.key == "matched").split(",")
                )

    try:
        with Probe("launch_probe") as probe:
            probe.node.create_subscription(VehicleHealth, HEALTH_TOPIC, health.append, HEALTH_QOS)
            probe.node.create_subscription(
                DiagnosticArray,
                "/diagnostics",
                on_diagnostics,
                RELIABLE_10,
            )
            for tid in ids:
                probe.node.create_subscription(
                    EscTelemetry,
                    f"/thruster/{tid}/esc/telemetry",
                    telemetry[tid].append,
                    qos_profile_sensor_data,
                )
                probe.node.create_subscription(
                    Residual, f"/thruster/{tid}/fdd/residual", residuals[tid].append, RESIDUAL_QOS
                )

            def recording() -> bool:
                return "/thruster/la/esc/telemetry" in matched

            probe.spin_until(
                lambda: (
                    all(len(residuals[t]) >= 10 and len(telemetry[t]) >= 50 for t in ids)
                    and recording()
                    and bool(health)
                    and expected_statuses <= statuses
                ),
                60.0,
                0.05,
            )
            topics = {name for name, _ in probe.node.get_topic_names_and_types()}
            recorded = recording()
            # The recorder takes its process's telemetry by direct calls, not over DDS.
            over_dds = [
                info.node_name
                for info in probe.node.get_subscriptions_info_by_topic("/thruster/la/esc/telemetry")
            ]
    finally:
        out = stop_launch(launch, stop, threads)
    assert all(len(telemetry[t]) >= 50 for t in ids), (
        {t: len(v) for t, v in telemetry.items()},
        out[-3000:],
    )
    assert all(len(residuals[t]) >= 10 for t in ids), out[-3000:]
    assert contract_topics(ids) - topics == set(), out[-3000:]
    assert recorded, "the recorder does not report the telemetry"
    assert over_dds == ["launch_probe"], over_dds
    assert health, f"nothing on {HEALTH_TOPIC}: {out[-3000:]}"
    assert [h.thruster_id for h in health[-1].thrusters] == list(ids)
    assert expected_statuses - statuses == set(), sorted(statuses)
    exits = [line.split() for line in out.splitlines() if line.startswith("exit ")]
    assert len(exits) == 1, out[-3000:]
    assert all(code == "0" for _, _, code in exits), out[-3000:]


def test_a_bag_the_launch_file_records_replays_to_the_live_windows(tmp_path: Path) -> None:
    """The recorder the launch file starts races the drivers, so its bag may begin mid-stream:
    replay and diagnose reproduce every live decision whose window and model history the bag
    holds, exactly, and count the rest."""
    pytest.importorskip("launch", reason=NOT_BUILT)
    pytest.importorskip("launch_ros", reason=NOT_BUILT)
    stop = threading.Event()
    params_file, threads = write_params(tmp_path, ("la",), stop)
    launch = start_launch(params_file)
    player = subprocess.Popen(
        [sys.executable, "-m", "thruster_fdd_shore.nodes.command_player", "--ros-args",
         "-r", "__ns:=/thruster/la", "-p", "signal:=multilevel"]
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 30.0  # the recorder's bag folder: the launch is up
        while time.monotonic() < deadline and not list(tmp_path.glob("rec/*/metadata.yaml")):
            time.sleep(0.5)
        time.sleep(40.0)
    finally:
        player.send_signal(signal.SIGINT)
        player.wait(timeout=30)
        out = stop_launch(launch, stop, threads)
    (bag,) = (tmp_path / "rec").iterdir()
    replay, result, offline = replay_and_diagnose(bag, tmp_path)
    (thruster,) = result["thrusters"]
    print(f"not comparable {thruster['not_comparable']}, labels {thruster['labels_compared']}")
    assert thruster["source"] == "recorded", out[-3000:]
    assert thruster["agreement"] == 1.0, thruster
    assert thruster["compared"] >= 10, thruster
    assert replay.returncode == 0, replay.stdout
    replayed = [round(t, 3) for t, _ in thruster["diagnoses"]]
    assert replayed == [round(w["t_end"], 3) for w in offline["windows"]]
    assert offline.get("not_comparable", {}) == thruster["not_comparable"]
