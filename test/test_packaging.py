"""The two packages as ROS and a vehicle see them: executables where ``ros2 run`` looks, every
import in each package.xml, a runtime requirement set that holds what the vehicle's nodes import,
and the vehicle's nodes running with the shore package and the heavy libraries unimportable."""

from __future__ import annotations

import ast
import json
import os
import re
import shutil
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "thruster_fdd"
NODES = PACKAGE / "thruster_fdd" / "nodes"
LAUNCH_FILE = PACKAGE / "launch" / "thruster_fdd.launch.py"
SHORE = ROOT / "src" / "thruster_fdd_shore"
SHORE_ONLY = (
    "thruster_fdd_shore",
    "torch",
    "scipy",
    "matplotlib",
    "sysidentpy",
    "tqdm",
    "dask",
    "distributed",
    "pyarrow",
)
"""What a vehicle does not install."""

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
SHORE_KEYS = {
    **ROSDEP_KEYS,
    "thruster_fdd": "thruster_fdd",
    "scipy": "python3-scipy",
    "matplotlib": "python3-matplotlib",
    "tqdm": "python3-tqdm",
    "threadpoolctl": "python3-threadpoolctl",
    "torch": "python3-torch",
    "sysidentpy": "python3-sysidentpy",
    "dask": "python3-dask",
    "distributed": "python3-distributed",
    "pyarrow": "python3-pyarrow",
}

# What importing the vehicle's code loads: every node module; printed as the thruster_fdd module
# files and the top-level modules, minus those a bare interpreter of this venv loads already
# (site hooks of development tools).
RUNTIME_IMPORTS = """
import importlib, json, pkgutil, sys
before = set(sys.modules)
import thruster_fdd.nodes as n
for m in pkgutil.walk_packages(n.__path__, "thruster_fdd.nodes."):
    importlib.import_module(m.name)
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
    return names - set(sys.stdlib_module_names)


def test_every_node_is_an_executable_where_ros2_run_looks() -> None:
    lib = ROOT / "install" / "thruster_fdd" / "lib" / "thruster_fdd"
    with_main = sorted(
        path.stem for path in NODES.glob("*.py") if "\ndef main(" in path.read_text()
    )
    assert with_main == [
        "classifier",
        "container",
        "esc_driver",
        "health",
        "nominal_model",
        "recorder",
    ]
    for name in with_main:
        assert os.access(lib / name, os.X_OK), f"no executable {lib / name}"
    player = ROOT / "install" / "thruster_fdd_shore" / "lib" / "thruster_fdd_shore"
    assert os.access(player / "command_player", os.X_OK)
    out = subprocess.run(
        [str(lib / "container"), "--help"], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert "--thrusters" in out.stdout
    cli = shutil.which("thruster-fdd")
    assert cli is not None
    assert Path(cli).parent == ROOT / "install" / "thruster_fdd_shore" / "bin"


def _declared(package: Path) -> set[str]:
    xml = ET.parse(package / "package.xml").getroot()
    return {e.text for e in xml.iter() if e.tag in ("exec_depend", "depend")}


def test_vehicle_package_xml_lists_every_import_and_nothing_else() -> None:
    files = [*sorted((PACKAGE / "thruster_fdd").rglob("*.py")), LAUNCH_FILE]
    imported = set().union(*(_direct_imports(f) for f in files)) - {"thruster_fdd", "setuptools"}
    unknown = imported - ROSDEP_KEYS.keys()
    assert not unknown, f"imported, no package.xml key known: {sorted(unknown)}"
    assert {ROSDEP_KEYS[name] for name in imported} == _declared(PACKAGE)


def test_shore_package_xml_lists_every_import_and_nothing_else() -> None:
    files = [*sorted((SHORE / "thruster_fdd_shore").rglob("*.py")), *(SHORE / "bin").iterdir()]
    imported = set().union(*(_direct_imports(f) for f in files)) - {
        "thruster_fdd_shore",
        "setuptools",
    }
    unknown = imported - SHORE_KEYS.keys()
    assert not unknown, f"imported, no package.xml key known: {sorted(unknown)}"
    assert {SHORE_KEYS[name] for name in imported} == _declared(SHORE)


def test_runtime_requirements_hold_what_the_nodes_import(runtime_imports: dict) -> None:
    from importlib.metadata import packages_distributions

    runtime = _pins(ROOT / "requirements-runtime.txt")
    built_here = {"thruster_fdd", "thruster_fdd_msgs"}
    # scipy: numba imports it when it is installed (see below).
    assert not (set(SHORE_ONLY) - {"scipy"}) & set(runtime_imports["tops"])
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
    heavy = {"torch", "scipy", "matplotlib", "sysidentpy", "tqdm", "dask", "distributed", "pyarrow"}
    assert not heavy & runtime.keys()


def test_runtime_requirements_pin_as_the_full_lock() -> None:
    full = _pins(ROOT / "requirements.txt")
    runtime = _pins(ROOT / "requirements-runtime.txt")
    differ = {name: (version, full.get(name)) for name, version in runtime.items()}
    assert {n: v for n, v in differ.items() if v[0] != v[1]} == {}


# Installed first in a vehicle process: modules a vehicle does not install cannot be imported.
BLOCKER = """
import importlib.abc, sys
class _Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {absent!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}} (not on a vehicle)")
        return None
sys.meta_path.insert(0, _Absent())
"""


def test_the_blocker_refuses_what_a_vehicle_lacks(tmp_path: Path) -> None:
    (tmp_path / "sitecustomize.py").write_text(BLOCKER.format(absent=SHORE_ONLY))
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}:{os.environ.get('PYTHONPATH', '')}"}
    out = subprocess.run(
        [sys.executable, "-c", "import thruster_fdd_shore"], env=env, capture_output=True, text=True
    )
    assert out.returncode != 0
    assert "not on a vehicle" in out.stderr


@pytest.mark.ros
@pytest.mark.slow
def test_the_vehicle_runs_without_the_shore(tmp_path: Path) -> None:
    """The vehicle container (driver, nominal model, classifier) and the health node, in
    interpreters where the shore package, torch, scipy, matplotlib, sysidentpy and tqdm cannot be
    imported, diagnose a thruster served by the emulator (a separate, shore process)."""
    from probe import Probe

    from thruster_fdd.lifetime import child_env, stop_children

    (tmp_path / "sitecustomize.py").write_text(BLOCKER.format(absent=SHORE_ONLY))
    vehicle_env = {**child_env(), "PYTHONPATH": f"{tmp_path}:{os.environ.get('PYTHONPATH', '')}"}
    link = tmp_path / "v0.tty"
    emulator = subprocess.Popen(
        [sys.executable, "-m", "thruster_fdd_shore.cli", "emulate", "--link", str(link)],
        env=child_env(),
    )
    params = tmp_path / "params.yaml"
    params.write_text(
        f"/thruster/v0/esc_driver:\n  ros__parameters:\n    port: {link}\n    autostart: true\n"
    )
    container = [
        sys.executable,
        "-m",
        "thruster_fdd.nodes.container",
        "esc_driver",
        "nominal_model",
        "classifier",
        "--thrusters",
        "v0",
        "--ros-args",
        "--params-file",
        str(params),
    ]
    health = [
        sys.executable,
        "-m",
        "thruster_fdd.nodes.health",
        "--ros-args",
        "-p",
        "thruster_ids:=[v0]",
    ]
    children = {"emulator": emulator}
    try:
        deadline = time.monotonic() + 30.0
        while not link.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert link.exists(), "the emulator never made its link"
        children["vehicle"] = subprocess.Popen(container, env=vehicle_env)
        children["health"] = subprocess.Popen(health, env=vehicle_env)
        from thruster_fdd_msgs.msg import Diagnosis, VehicleHealth

        with Probe("vehicle_probe") as probe:
            diagnoses: list = []
            healths: list = []
            probe.node.create_subscription(
                Diagnosis, "/thruster/v0/fdd/diagnosis", diagnoses.append, 10
            )
            probe.node.create_subscription(
                VehicleHealth, "/thruster_fdd/health", healths.append, 10
            )
            seen = probe.spin_until(
                lambda: diagnoses and any(not h.stale_mask for h in healths), 90.0, 0.2
            )
            alive = {n: c.poll() for n, c in children.items()}
            assert seen, f"no diagnosis and fresh health in 90 s (exit codes {alive})"
    finally:
        stop_children(children, timeout_s=10.0)
