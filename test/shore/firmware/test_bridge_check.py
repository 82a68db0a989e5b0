"""bridge_check, the ROS-free check of a flashed bridge, against the co-simulated firmware."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from thruster_fdd.core.bridge.tfdd import StatusFlag
from thruster_fdd_shore.core.bridge import bridge_check
from thruster_fdd_shore.core.bridge import firmware_cosim as cosim
from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator


@pytest.fixture(scope="module")
def bridge(
    firmware_images: dict, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[cosim.FirmwareBridge]:
    link = tmp_path_factory.mktemp("pty") / "check.tty"
    simulator = ThrusterSimulator(load_config("t100"), "nominal_15v", seed=8)
    firmware = cosim.FirmwareBridge(simulator, link, firmware_images["hott"])
    firmware.open()
    stop = threading.Event()
    thread = threading.Thread(target=firmware.run, args=(stop,), daemon=True)
    thread.start()
    try:
        yield firmware
    finally:
        stop.set()
        thread.join(timeout=5)


def test_a_healthy_bridge_passes_and_applies_the_pulse(
    bridge: cosim.FirmwareBridge, capsys: pytest.CaptureFixture[str]
) -> None:
    deadline = time.monotonic() + 10.0
    while bridge.virtual_time < 2.3 and time.monotonic() < deadline:
        time.sleep(0.05)  # arming: the bridge applies no pulse for 2 s after a reset
    # --rate 30: a loaded machine may run the co-simulation below real time.
    argv = [str(bridge.link), "--pulse", "1600", "--seconds", "2", "--rate", "30"]
    assert bridge_check.main(argv) == 0, capsys.readouterr().out
    out = capsys.readouterr().out
    assert "firmware: 1.0.0" in out
    assert "last: pulse 1600 µs" in out
    assert out.strip().endswith("bridge OK")
    end = bridge.virtual_time + 0.1
    while bridge.virtual_time < end and time.monotonic() < deadline + 5.0:
        time.sleep(0.01)
    assert abs(list(bridge.pulses)[-1].width_us - 1500) <= 0.5, "the check ends in neutral"


def test_a_silent_esc_is_reported(bridge: cosim.FirmwareBridge) -> None:
    bridge.inject(cosim.EscSilence(3.0))
    report = bridge_check.check_bridge(str(bridge.link), seconds=2.0)
    assert any("ESC's telemetry is not valid" in p for p in report.problems(50.0))
    assert report.flags_seen & StatusFlag.ESC_TIMEOUT


def test_a_port_that_does_not_open_is_exit_2(tmp_path: Path) -> None:
    assert bridge_check.main([str(tmp_path / "nothing")]) == 2
    assert bridge_check.main([str(tmp_path / "nothing"), "--pulse", "2500"]) == 2
