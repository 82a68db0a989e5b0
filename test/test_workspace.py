"""The workspace: the cores stay ROS-free, the vehicle package never imports the shore, the CLI
answers --help, messages carry their contract."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from thruster_fdd_shore.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = ROOT / "src" / "thruster_fdd"
CORE = VEHICLE / "thruster_fdd" / "core"
SHORE_CORE = ROOT / "src" / "thruster_fdd_shore" / "thruster_fdd_shore" / "core"
FORBIDDEN_IN_CORE = (
    "rclpy",
    "rosidl_runtime_py",
    "thruster_fdd_msgs",
    "std_msgs",
    "diagnostic_msgs",
    "builtin_interfaces",
    "thruster_fdd.nodes",
)
SUBCOMMANDS = (
    "simulate",
    "train",
    "evaluate",
    "diagnose",
    "discrepancy",
    "replay",
    "up",
    "record",
    "reload",
    "reference",
    "emulate",
    "fleet",
)


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def ros_imports_in(folder: Path) -> dict[str, list[str]]:
    """Files below ``folder`` that import ROS packages, with the offending modules."""
    found: dict[str, list[str]] = {}
    for path in sorted(folder.rglob("*.py")):
        bad = [
            name
            for name in _imports(path)
            if any(name == f or name.startswith(f + ".") for f in FORBIDDEN_IN_CORE)
        ]
        if bad:
            found[str(path.relative_to(folder))] = sorted(bad)
    return found


def test_cores_do_not_import_ros() -> None:
    for core in (CORE, SHORE_CORE):
        assert list(core.glob("*.py")), f"{core} not found"
        assert ros_imports_in(core) == {}


def test_the_vehicle_package_never_imports_the_shore() -> None:
    found = {
        str(path.relative_to(VEHICLE)): sorted(bad)
        for path in sorted(VEHICLE.rglob("*.py"))
        if (bad := [n for n in _imports(path) if n.split(".")[0] == "thruster_fdd_shore"])
    }
    assert found == {}


def test_core_check_catches_a_ros_import(tmp_path: Path) -> None:
    (tmp_path / "bad.py").write_text("import numpy\nfrom rclpy.node import Node\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "worse.py").write_text("def f():\n    import thruster_fdd_msgs.msg\n")
    assert ros_imports_in(tmp_path) == {
        "bad.py": ["rclpy.node"],
        "sub/worse.py": ["thruster_fdd_msgs.msg"],
    }


def test_core_imports_without_rclpy_loaded() -> None:
    code = (
        "import sys, importlib, pkgutil, thruster_fdd.core as c\n"
        "for m in pkgutil.walk_packages(c.__path__, 'thruster_fdd.core.'):\n"
        "    importlib.import_module(m.name)\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
        "('rclpy', 'thruster_fdd_msgs', 'std_msgs', 'diagnostic_msgs'))\n"
        "print(bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_nodes_import_neither_torch_nor_training_code() -> None:
    code = (
        "import sys, importlib, pkgutil, thruster_fdd.nodes as n\n"
        "for m in pkgutil.walk_packages(n.__path__, 'thruster_fdd.nodes.'):\n"
        "    importlib.import_module(m.name)\n"
        "heavy = ('torch', 'tqdm', 'scipy.optimize', 'matplotlib', 'sysidentpy')\n"
        "print(sorted(m for m in heavy if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"


@pytest.mark.parametrize("subcommand", SUBCOMMANDS)
def test_cli_help_for_every_subcommand(subcommand: str) -> None:
    out = subprocess.run(
        ["thruster-fdd", subcommand, "--help"], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"usage: thruster-fdd {subcommand}")


def test_cli_lists_every_subcommand() -> None:
    help_text = build_parser().format_help()
    for subcommand in SUBCOMMANDS:
        assert subcommand in help_text


def test_cli_bad_input_is_one_line_and_exit_2() -> None:
    out = subprocess.run(
        ["thruster-fdd", "simulate", "--out", "x.csv", "--condition", "bogus"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1
    assert "bogus" in out.stderr


def test_message_contract() -> None:
    from thruster_fdd_msgs.msg import Diagnosis, EscTelemetry, Residual, ThrusterCommand

    from thruster_fdd.core.labels import CLASS_NAMES

    telemetry = EscTelemetry.get_fields_and_field_types()
    for field in ("voltage_v", "current_a", "rpm", "pwm_us", "temperature_c", "command"):
        assert field in telemetry
    assert "command" in ThrusterCommand.get_fields_and_field_types()
    assert {"residual_rpm", "residual_current_a", "model_id"} <= set(
        Residual.get_fields_and_field_types()
    )
    constants = [getattr(Diagnosis, name.upper()) for name in CLASS_NAMES]
    assert sorted(constants) == list(range(1, len(CLASS_NAMES) + 1))
    assert Diagnosis.UNKNOWN == 0
    from thruster_fdd_msgs.msg import ThrusterHealth, VehicleHealth

    assert {"effectiveness", "effectiveness_std", "faulty", "condition", "label"} <= set(
        ThrusterHealth.get_fields_and_field_types()
    )
    assert {"thrusters", "faulty_mask", "stale_mask"} <= set(
        VehicleHealth.get_fields_and_field_types()
    )


@pytest.mark.parametrize(
    "module",
    [
        "thruster_fdd.nodes.esc_driver",
        "thruster_fdd.nodes.nominal_model",
        "thruster_fdd.nodes.recorder",
        "thruster_fdd.nodes.classifier",
        "thruster_fdd.nodes.health",
        "thruster_fdd_shore.nodes.command_player",
    ],
)
def test_readme_lists_every_node_parameter_with_its_default(module: str) -> None:
    import importlib

    readme = (ROOT / "README.md").read_text()
    node = importlib.import_module(module)
    for name, default, _ in node.PARAMETERS:
        assert f"| `{name}` | `{default}` |" in readme, f"{module}.{name} missing from README"


def test_train_nominal_records_its_recordings(tmp_path: Path) -> None:
    import hashlib
    import json

    from thruster_fdd.core.nominal.runtime import NominalModel
    from thruster_fdd.core.traces.mcap_io import write_trace_mcap
    from thruster_fdd_shore.core.sim.scenario import run_scenario

    logs = tmp_path / "logs"
    trace = run_scenario("t100", "nominal_15v", signal="multilevel", duration_s=60, seed=3)
    write_trace_mcap([trace], logs / "run1.mcap")
    out = subprocess.run(
        ["thruster-fdd", "train", "nominal", "--data", str(logs), "--out", str(tmp_path / "m"),
         "--epochs", "1", "--finetune-epochs", "0"],
        capture_output=True,
        text=True,
        timeout=300,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    card = json.loads((tmp_path / "m" / "model_card.json").read_text())
    (entry,) = card["extra"]["training_files"]
    assert entry["file"].endswith("run1.mcap")
    assert entry["sha256"] == hashlib.sha256((logs / "run1.mcap").read_bytes()).hexdigest()
    assert NominalModel.load(tmp_path / "m").model_id == card["model_id"]
