"""The microcontroller emulator alone: a real pty, frames at rate, commands applied."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path

import pytest
import serial

from thruster_fdd.core.bridge.plausibility import check_telemetry
from thruster_fdd.core.bridge.tfdd import (
    CommandFrame,
    DecodedFrame,
    FrameDecoder,
    StatusFlag,
    classify_seq,
    encode_command,
)
from thruster_fdd_shore.core.bridge.emulator import (
    BridgeEmulator,
    EmulatorSettings,
    OutOfRange,
    SetCondition,
    SkipSequence,
)
from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator


@pytest.fixture
def running(tmp_path: Path) -> Iterator[tuple[BridgeEmulator, serial.Serial]]:
    sim = ThrusterSimulator(load_config("t100"), "nominal_13v", seed=1)
    emulator = BridgeEmulator(sim, tmp_path / "dev" / "t0.tty", EmulatorSettings(rate_hz=50.0))
    device = emulator.open()
    assert os.path.realpath(emulator.link) == device
    stop = threading.Event()
    thread = threading.Thread(target=emulator.run, args=(stop,), daemon=True)
    thread.start()
    port = serial.Serial(str(emulator.link), 115200, timeout=0.05)
    try:
        yield emulator, port
    finally:
        port.close()
        stop.set()
        thread.join(timeout=5)


def _read_frames(
    port: serial.Serial, seconds: float, decoder: FrameDecoder | None = None
) -> list[DecodedFrame]:
    decoder = decoder or FrameDecoder()
    frames: list[DecodedFrame] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        frames += decoder.feed(port.read(256))
    return frames


def test_telemetry_at_rate_with_consecutive_sequence(running: tuple) -> None:
    _, port = running
    frames = _read_frames(port, 1.0)
    assert 40 <= len(frames) <= 60
    seqs = [f.seq for f in frames]
    assert all(b - a == 1 for a, b in pairwise(seqs))
    volts = [f.message.voltage_v for f in frames]
    assert min(volts) > 12.5
    assert max(volts) < 13.5


def test_commands_drive_the_thruster_and_the_bridge_watchdog_stops_it(running: tuple) -> None:
    emulator, port = running
    for seq in range(40):
        port.write(encode_command(CommandFrame(1800, 300), seq))
        time.sleep(0.05)
    assert emulator.pwm_us == 1800
    assert emulator.last_sample is not None
    assert emulator.last_sample.rpm > 1500
    time.sleep(0.5)
    assert emulator.pwm_us == 1500
    frames = _read_frames(port, 0.3)
    assert frames[-1].message.status & StatusFlag.ESC_TIMEOUT


def test_injected_faults_show_on_the_wire(running: tuple) -> None:
    emulator, port = running
    decoder = FrameDecoder()
    frames = _read_frames(port, 0.2, decoder)
    emulator.inject(SkipSequence(9))
    emulator.inject(OutOfRange(2))
    frames += _read_frames(port, 0.5, decoder)
    gaps = [classify_seq(a.seq, b.seq) for a, b in pairwise(frames)]
    assert any(g.status == "lost" and g.lost == 9 for g in gaps)
    assert sum(1 for f in frames if check_telemetry(f.message)) == 2
    emulator.inject(SetCondition("biofouling"))
    time.sleep(0.1)
    assert emulator._sim.condition == "biofouling"
