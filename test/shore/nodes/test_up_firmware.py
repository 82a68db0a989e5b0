"""`thruster-fdd up --bridge firmware`: the whole node set on the co-simulated bridge firmware."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_up_runs_the_node_set_on_the_bridge_firmware(tmp_path: Path) -> None:
    cmd = ["thruster-fdd", "up", "--bridge", "firmware", "--duration", "16", "--print-period", "4"]
    cmd += ["--keep-run-dir"]  # the test reads the emulator logs afterwards
    out = subprocess.run(
        [*cmd, "--record-dir", str(tmp_path)], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    final = out.stdout.split("final:")[1]
    (row,) = re.findall(r"^t0\s+([\d.]+)\s+(-?[\d.]+)\s+(\d+)\s+([\d.]+)\s.*$", final, re.M)
    rate, _command, pwm, voltage = row
    assert 40.0 <= float(rate) <= 60.0, final
    assert 1100 <= int(pwm) <= 1900
    assert 14.0 < float(voltage) < 16.0
    assert "OK: telemetry" in final, final
    run_dir = Path(re.search(r"ports, parameters and logs: (\S+)", out.stdout)[1])
    emulator_log = (run_dir / "t0-emulator.log").read_text()
    assert "bridge firmware bridge_hott.hex on an emulated ATmega328P" in emulator_log
    print(emulator_log.strip().splitlines()[-1])
    assert list(tmp_path.glob("up_*/up_*.mcap")), out.stdout
