"""Every node executable's command line: ``--help`` lists the parameters with units, defaults
and ranges (from the descriptors) and exits 0 without starting a node; a bad parameter is one
line on stderr and exit 2."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

from thruster_fdd.nodes.common import parameter_descriptor, parameter_unit

SETUP = Path(__file__).resolve().parents[3] / "src" / "thruster_fdd" / "setup.py"
# name = module:main of every console script of the vehicle package.
EXECUTABLES = dict(re.findall(r'"(\w+) = (thruster_fdd\.nodes\.\w+):main"', SETUP.read_text()))
NODES = sorted(set(EXECUTABLES) - {"container"})


def _run(module: str, *args: str, timeout: float = 30.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", module, *args], capture_output=True, text=True, timeout=timeout
    )


def test_every_node_executable_is_covered() -> None:
    assert set(NODES) == {
        "esc_driver",
        "nominal_model",
        "classifier",
        "recorder",
        "health",
    }


@pytest.mark.parametrize("name", NODES)
def test_help_lists_the_parameters_and_exits_without_a_node(name: str) -> None:
    module = importlib.import_module(EXECUTABLES[name])
    done = _run(EXECUTABLES[name], "--help", timeout=20.0)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith(f"usage: {name} ")
    limits = {**getattr(module, "LIMITS", {})}
    for pname, default, description in module.PARAMETERS:
        (line,) = [x for x in done.stdout.splitlines() if x.startswith(f"  {pname}  (")]
        assert f"default {default!r}" in line, line
        unit = parameter_unit(description)
        if unit:
            assert f"unit {unit}" in line, line
        if pname in limits and not isinstance(limits[pname][0], str):
            assert "range " in line, line
        assert description in done.stdout


def test_esc_driver_help_shows_units_and_ranges() -> None:
    done = _run("thruster_fdd.nodes.esc_driver", "-h")
    assert done.returncode == 0
    assert "baud  (integer; default 115200; unit bit/s; range 1200..4000000)" in done.stdout
    assert "protocol  (string; default 'tfdd'; one of tfdd, kiss)" in done.stdout
    assert "rate_hz  (double; default 50.0; unit Hz; range 0.1..10000)" in done.stdout


def test_container_help_exits_0() -> None:
    done = _run("thruster_fdd.nodes.container", "--help")
    assert done.returncode == 0
    assert "<kind> --help" in done.stdout


@pytest.mark.parametrize(
    ("module", "args", "expected"),
    [
        (
            "thruster_fdd.nodes.esc_driver",
            ["--ros-args", "-p", "baud:=fast"],
            "esc_driver: parameter baud: 'fast' is not an integer (default 115200)",
        ),
        (
            "thruster_fdd.nodes.esc_driver",
            ["--ros-args", "-p", "rate_hz:=-3.0"],
            "esc_driver: parameter rate_hz: -3.0 is out of range 0.1..10000",
        ),
        (
            "thruster_fdd.nodes.esc_driver",
            ["--ros-args", "-p", "protocol:=mavlink"],
            "esc_driver: parameter protocol: 'mavlink' is not one of tfdd, kiss",
        ),
        (
            "thruster_fdd.nodes.esc_driver",
            ["--ros-args", "-p", "rate_hz:=50"],
            "esc_driver: parameter rate_hz: 50 is an integer, the parameter a double (write 50.0)",
        ),
        (
            "thruster_fdd.nodes.esc_driver",
            ["--ros-args", "-p", "baud"],
            "esc_driver: bad command line: Failed to parse ROS arguments: "
            "Couldn't parse parameter override rule: '-p baud'",
        ),
        (
            "thruster_fdd.nodes.recorder",
            ["--ros-args", "-p", "compression:=gzip"],
            "recorder: parameter compression: 'gzip' is not one of zstd, lz4, none",
        ),
        (
            "thruster_fdd.nodes.nominal_model",
            ["--ros-args", "-p", "max_gap_periods:=0.0"],
            "nominal_model: parameter max_gap_periods: 0.0 is out of range 1..1000",
        ),
        (
            "thruster_fdd.nodes.container",
            ["esc_driver", "--thrusters", "x0", "-p", "esc_driver:baud=fast"],
            "container esc_driver: parameter baud: 'fast' is not an integer (default 115200)",
        ),
    ],
)
def test_a_bad_parameter_is_one_line_and_exit_2(
    module: str, args: list[str], expected: str
) -> None:
    done = _run(module, *args)
    assert done.returncode == 2, done.stderr[-2000:]
    assert done.stderr.strip() == expected
    assert "Traceback" not in done.stderr


def test_descriptors_carry_the_ranges() -> None:
    integer = parameter_descriptor("baud", 115200, "serial baud rate, bit/s", (1200, 4_000_000))
    assert (integer.integer_range[0].from_value, integer.integer_range[0].to_value) == (
        1200,
        4_000_000,
    )
    real = parameter_descriptor("rate_hz", 50.0, "rate, Hz", (0.1, 10_000.0))
    assert real.floating_point_range[0].to_value == 10_000.0
    choice = parameter_descriptor("protocol", "tfdd", "format", ("tfdd", "kiss"))
    assert choice.additional_constraints == "one of tfdd, kiss"
    assert parameter_unit("period of /thruster_fdd/health, s (also published on change)") == "s"
    assert parameter_unit("motor pole pairs, to turn KISS eRPM into rpm") == ""
