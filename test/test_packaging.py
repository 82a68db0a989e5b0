"""The package as ROS and a vehicle see it: executables where ``ros2 run`` looks, every runtime
dependency in package.xml, and a runtime requirement set that holds what the nodes import."""

from __future__ import annotations

import ast
import json
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "thruster_fdd"
NODES = PACKAGE / "thruster_fdd" / "nodes"
LAUNCH_FILE = PACKAGE / "launch" / "thruster_fdd.launch.py"

# Top-level module -> the package.xml key that provides it.
ROSDEP_KEYS = {
    "rclpy": "rclpy",
    "rcl_interfaces": "rcl_interfaces",
    "builtin_interfaces": "builtin_interfaces",
    "std_msgs": "std_msgs",
    "diagnostic_msgs": "diagnostic_msgs",
    "lifecycle_msgs": "lifecycle_msgs",
    "thruster_fdd_msgs": "thruster_fdd_msgs",
    "ament_index_python": "ament_index_python",
    "launch": "launch",
    "launch_ros": "launch_ros",
    "numpy": "python3-numpy",
    "numba": "python3-numba",
    "serial": "python3-serial",
    "yaml": "python3-yaml",
    "zstandard": "python3-zstandard",
    "lz4": "python3-lz4",
    "mcap": "python3-mcap",
    "mcap_ros2": "python3-mcap-ros2-support",
    # Optional: the recorder's last source of message definitions (an empty one without it).
    # The key follows rosdep's python3-<name> convention; not checked against rosdistro here.
    "rosbags": "python3-rosbags",
}

# What importing the vehicle's code loads: every node module and `thruster-fdd up`; printed as
# the thruster_fdd module files and the top-level modules, minus those a bare interpreter of this
# venv loads already (site hooks of development tools).
RUNTIME_IMPORTS = """
import importlib, json, pkgutil, sys
before = set(sys.modules)
import thruster_fdd.nodes as n
for m in pkgutil.walk_packages(n.__path__, "thruster_fdd.nodes."):
    importlib.import_module(m.name)
import thruster_fdd.commands.up
files = sorted({m.__file__ for k, m in sys.modules.items()
                if k.startswith("thruster_fdd.") and getattr(m, "__file__", None)})
tops = sorted({k.split(".")[0] for k in set(sys.modules) - before} - set(sys.stdlib_module_names))
print(json.dumps({"files": files, "tops": tops}))
"""


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _pins(path: Path) -> dict[str, str]:
    out = {}
    for line in path.read_text().splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            name, _, version = line.partition("==")
            out[_norm(name)] = version
    return out


@pytest.fixture(scope="module")
def runtime_imports() -> dict[str, list[str]]:
    out = subprocess.run(
        [sys.executable, "-c", RUNTIME_IMPORTS], capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def _direct_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - {"thruster_fdd"}


def test_every_node_is_an_executable_where_ros2_run_looks() -> None:
    lib = ROOT / "install" / "thruster_fdd" / "lib" / "thruster_fdd"
    with_main = sorted(
        path.stem for path in NODES.glob("*.py") if "\ndef main(" in path.read_text()
    )
    assert with_main == [
        "classifier",
        "command_player",
        "container",
        "esc_driver",
        "health",
        "nominal_model",
        "recorder",
    ]
    for name in with_main:
        assert os.access(lib / name, os.X_OK), f"no executable {lib / name}"
    out = subprocess.run(
        [str(lib / "container"), "--help"], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert "--thrusters" in out.stdout
    cli = shutil.which("thruster-fdd")
    assert cli is not None
    assert Path(cli).parent == ROOT / "install" / "thruster_fdd" / "bin"


def test_package_xml_lists_every_runtime_dependency(runtime_imports: dict) -> None:
    files = [Path(f) for f in runtime_imports["files"]] + [LAUNCH_FILE]
    imported = set().union(*(_direct_imports(f) for f in files))
    unknown = imported - ROSDEP_KEYS.keys()
    assert not unknown, f"imported at run time, no package.xml key known: {sorted(unknown)}"
    xml = ET.parse(PACKAGE / "package.xml").getroot()
    declared = {e.text for e in xml.iter() if e.tag in ("exec_depend", "depend")}
    missing = {ROSDEP_KEYS[name] for name in imported} - declared
    assert not missing, f"package.xml lacks exec_depend {sorted(missing)}"


def test_runtime_requirements_hold_what_the_nodes_import(runtime_imports: dict) -> None:
    from importlib.metadata import packages_distributions

    runtime = _pins(ROOT / "requirements-runtime.txt")
    built_here = {"thruster_fdd", "thruster_fdd_msgs"}
    # numba imports scipy (a version check) and coverage (its coverage support) when they are
    # installed; a vehicle does not install them.
    optional = {"scipy", "coverage"}
    by_module = packages_distributions()
    missing = [
        top
        for top in runtime_imports["tops"]
        if top in by_module  # not an interpreter or Cython internal
        and top not in built_here | optional
        and not any(_norm(d) in runtime for d in by_module[top])
    ]
    assert not missing, f"imported by the nodes, not in requirements-runtime.txt: {missing}"
    heavy = {"torch", "scipy", "matplotlib", "sysidentpy", "tqdm"}
    assert not heavy & runtime.keys()


def test_runtime_requirements_pin_as_the_full_lock() -> None:
    full = _pins(ROOT / "requirements.txt")
    runtime = _pins(ROOT / "requirements-runtime.txt")
    differ = {name: (version, full.get(name)) for name, version in runtime.items()}
    assert {n: v for n, v in differ.items() if v[0] != v[1]} == {}
