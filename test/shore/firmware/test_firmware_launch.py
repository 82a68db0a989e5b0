"""`up --bridge firmware`, a config's `bridge:` key and `emulate --bridge firmware`: the plans and
their refusals (the run itself is test/nodes/test_up_firmware.py)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from thruster_fdd_shore.cli import build_parser
from thruster_fdd_shore.commands.up import ThrusterPlan, plan_from_args


def _plans(*argv: str) -> tuple[ThrusterPlan, ...]:
    return plan_from_args(build_parser().parse_args(["up", *argv]))[1]


def test_the_bridge_option_reaches_every_simulated_thruster() -> None:
    assert {p.bridge for p in _plans("--thrusters", "2")} == {"python"}
    assert {p.bridge for p in _plans("--thrusters", "2", "--bridge", "firmware")} == {"firmware"}


def test_a_config_key_wins_over_the_option_and_real_thrusters_keep_theirs(tmp_path: Path) -> None:
    config = tmp_path / "up.yaml"
    config.write_text(
        "rate_hz: 20\nthrusters:\n"
        "  - {id: a, bridge: firmware}\n"
        "  - {id: b}\n"
        "  - {id: c, bridge: python}\n"
        "  - {id: d, port: /dev/ttyUSB0}\n"
    )
    plans = {p.id: p.bridge for p in _plans("--config", str(config))}
    assert plans == {"a": "firmware", "b": "python", "c": "python", "d": "python"}
    plans = {p.id: p.bridge for p in _plans("--config", str(config), "--bridge", "firmware")}
    assert plans == {"a": "firmware", "b": "firmware", "c": "python", "d": "python"}


@pytest.mark.parametrize(
    ("plan", "words"),
    [
        ({"bridge": "arduino"}, "bridge must be one of"),
        ({"bridge": "firmware", "port": "/dev/ttyUSB0"}, "for simulated thrusters"),
        ({"bridge": "firmware", "protocol": "kiss"}, "speaks tfdd"),
    ],
)
def test_a_plan_the_firmware_cannot_serve_is_refused(plan: dict, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        ThrusterPlan(id="t0", **plan)


@pytest.mark.parametrize("rate", ["25.5", "200"])
def test_up_refuses_a_rate_the_firmware_cannot_send(rate: str) -> None:
    with pytest.raises(ValueError, match=r"10\.\.100 whole Hz"):
        _plans("--bridge", "firmware", "--rate", rate)


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--protocol", "kiss"], "speaks tfdd to the host"),
        (["--rate", "12.5"], "whole Hz"),
        (["--rate", "5"], "10..100 Hz"),
    ],
)
def test_emulate_refuses_firmware_options_in_one_line(
    tmp_path: Path, extra: list[str], words: str
) -> None:
    cmd = ["thruster-fdd", "emulate", "--bridge", "firmware", "--link", str(tmp_path / "x.tty")]
    out = subprocess.run([*cmd, *extra], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert words in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
