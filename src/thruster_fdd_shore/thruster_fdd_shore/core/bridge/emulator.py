"""Microcontroller emulator: the thruster's serial bridge, served on a pseudo-terminal.

A :class:`BridgeEmulator` runs the physics simulator in real time behind the bridge protocol of
``docs/protocol.md``: it writes telemetry frames at a fixed rate and applies the command frames it
reads, with the bridge's own watchdog. The port is a real tty (``os.openpty``) published under a
stable symlink, so the ESC driver opens it with pyserial exactly as it opens a USB serial adapter.
Faults (garbage, bad CRC, truncated frames, sequence jumps, replayed frames, a bridge reset,
a line stuck low or high, implausible values, an unplugged port, silence) are injected on
request, which is how the driver's tests exercise it. Like the firmware, the first frame after
start (and after a reset) carries the RESET status bit.
"""

from __future__ import annotations

import contextlib
import os
import queue
import select
import threading
import time
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from thruster_fdd.core.bridge.kiss import KissFrame, encode_kiss
from thruster_fdd.core.bridge.tfdd import (
    NEUTRAL_PWM_US,
    PWM_PER_UNIT,
    SEQ_MODULUS,
    CommandFrame,
    FrameDecoder,
    StatusFlag,
    TelemetryFrame,
    encode_telemetry,
)
from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.core.bridge.pty_link import PtyLink
from thruster_fdd_shore.core.sim.physics import Sample, ThrusterSimulator

PROTOCOLS: tuple[str, ...] = ("tfdd", "kiss")


@dataclass(frozen=True)
class EmulatorSettings:
    """How the emulated bridge talks.

    Attributes
    ----------
    rate_hz : float
        Telemetry frames per second (10-100 Hz on the real bridge).
    protocol : str
        Telemetry format: ``"tfdd"`` (the project's bridge protocol) or ``"kiss"`` (KISS /
        BLHeli_32 10-byte ESC telemetry). Commands always arrive as tfdd COMMAND frames.
    pole_pairs : int
        Motor pole pairs, to turn rpm into the eRPM that KISS telemetry carries.
    command_timeout_s : float
        Bridge watchdog used until a command frame sets its own: no command for this long
        drives the ESC to neutral.
    """

    rate_hz: float = 50.0
    protocol: str = "tfdd"
    pole_pairs: int = 7
    command_timeout_s: float = 1.0

    def __post_init__(self) -> None:
        if not 1.0 <= self.rate_hz <= 1000.0:
            raise BadInputError(f"rate_hz must be within 1..1000 Hz, got {self.rate_hz}")
        if self.protocol not in PROTOCOLS:
            raise BadInputError(f"protocol must be one of {PROTOCOLS}, got {self.protocol!r}")
        if not 1 <= self.pole_pairs <= 255:
            raise BadInputError(f"pole_pairs must be within 1..255, got {self.pole_pairs}")
        if not 0 < self.command_timeout_s < float("inf"):
            raise BadInputError(f"command_timeout_s must be > 0, got {self.command_timeout_s}")


@dataclass(frozen=True)
class Garbage:
    """Write ``n_bytes`` of random bytes between two frames."""

    n_bytes: int = 64


@dataclass(frozen=True)
class CorruptCrc:
    """Send the next ``n_frames`` frames with one payload bit flipped (CRC no longer matches)."""

    n_frames: int = 1


@dataclass(frozen=True)
class Truncate:
    """Send only the first half of the next ``n_frames`` frames."""

    n_frames: int = 1


@dataclass(frozen=True)
class DuplicateFrame:
    """Send the next frame twice with the same sequence number."""

    n_frames: int = 1


@dataclass(frozen=True)
class SkipSequence:
    """Jump the sequence number by ``n`` (as if ``n`` frames were lost on the wire)."""

    n: int = 5


@dataclass(frozen=True)
class ReplayFrames:
    """Send again ``count`` frames as they were sent, starting ``back`` frames ago (a bridge
    re-sending its buffer): same sequence numbers, same bytes."""

    back: int = 5
    count: int = 5


@dataclass(frozen=True)
class BridgeReset:
    """Restart the microcontroller: sequence and clock from 0, the next frame carries RESET."""


@dataclass(frozen=True)
class StuckLine:
    """Hold the line at one level for ``duration_s``: ``byte`` 0x00 (stuck low, UART breaks)
    or 0xFF (stuck high) at the line's byte rate instead of frames."""

    byte: int = 0x00
    duration_s: float = 1.0


@dataclass(frozen=True)
class OutOfRange:
    """Report an implausible bus voltage in the next ``n_frames`` frames (a bridge ADC fault)."""

    n_frames: int = 1


@dataclass(frozen=True)
class Disconnect:
    """Unplug the port for ``duration_s``: the tty vanishes and a new one appears at the link."""

    duration_s: float = 1.0


@dataclass(frozen=True)
class Silence:
    """Send nothing for ``duration_s`` while the port stays open."""

    duration_s: float = 1.0


@dataclass(frozen=True)
class SetCondition:
    """Change the simulated thruster's condition (fault onset), keeping its state."""

    condition: str


Fault = (
    Garbage
    | CorruptCrc
    | Truncate
    | DuplicateFrame
    | SkipSequence
    | ReplayFrames
    | BridgeReset
    | StuckLine
    | OutOfRange
    | Disconnect
    | Silence
    | SetCondition
)


# Where CorruptCrc flips a bit: the voltage's low byte (+-0.64 V), a change that stays
# plausible, so only the CRC can catch it.
_VOLTAGE_LOW_BYTE = {"tfdd": 13, "kiss": 2}


# Voltage the OutOfRange fault reports: representable on the wire, far outside any thruster bus.
_IMPLAUSIBLE_VOLTAGE_V = 600.0


# Frames kept for ReplayFrames.
_HISTORY = 256


# Bytes per second of a line at 115200 baud (8N1: 10 bit times per byte).
_LINE_BYTES_PER_S = 11_520


@dataclass(frozen=True)
class _Pending:
    """Counts of frame-level faults still to apply (immutable; replaced on every change)."""

    corrupt: int = 0
    truncate: int = 0
    duplicate: int = 0
    out_of_range: int = 0


class BridgeEmulator:
    """A simulated thruster behind its serial bridge, on a pseudo-terminal.

    Parameters
    ----------
    simulator : ThrusterSimulator
        The thruster; stepped by ``1 / rate_hz`` s per telemetry frame.
    link : str or Path
        Path of the symlink to the pty's slave device: the port name the driver opens. Its
        folder is created; an existing symlink is replaced, anything else at that path is
        refused (``open`` raises BadInputError), so a typo never deletes a file.
    settings : EmulatorSettings
        Rate and telemetry format.
    seed : int
        Seed of the garbage bytes.
    """

    def __init__(
        self,
        simulator: ThrusterSimulator,
        link: str | Path,
        settings: EmulatorSettings | None = None,
        *,
        seed: int = 0,
    ) -> None:
        self._sim = simulator
        self._link = Path(link)
        self._settings = settings or EmulatorSettings()
        self._faults: queue.SimpleQueue[Fault] = queue.SimpleQueue()
        self._pending = _Pending()
        self._rng = np.random.default_rng(seed)
        self._decoder = FrameDecoder()
        self._pty: PtyLink | None = None
        self._master: int | None = None
        self._seq = 0
        self._boot = time.monotonic()
        self._reset_pending = True
        self._history: deque[bytes] = deque(maxlen=_HISTORY)
        self._pwm_us = NEUTRAL_PWM_US
        self._command_timeout_s = self._settings.command_timeout_s
        self._last_command = time.monotonic()
        self._silent_until = 0.0
        self._stuck: tuple[int, float] | None = None
        self._timed_out = False
        self._consumption_mah = 0.0
        self.frames_sent = 0
        self.commands_received = 0
        self.last_sample: Sample | None = None

    @property
    def link(self) -> Path:
        """The port name the driver opens."""
        return self._link

    @property
    def pwm_us(self) -> int:
        """The pulse width the bridge currently applies to the ESC, in µs."""
        return self._pwm_us

    def open(self) -> str:
        """Create the pty and point the link at it; returns the slave device path.

        Raises
        ------
        BadInputError
            If something other than a symlink exists at the link path.
        """
        self._pty = PtyLink.open(self._link)
        self._master = self._pty.master
        return self._pty.device

    def close(self) -> None:
        """Remove the link and close the pty (the driver sees the port vanish).

        The link is removed only while it still points at this emulator's pty.
        """
        if self._pty is not None:
            self._pty.close()
        self._pty = None
        self._master = None

    def inject(self, fault: Fault) -> None:
        """Queue a fault; it takes effect at the next telemetry tick. Thread-safe."""
        self._faults.put(fault)

    def run(self, stop: threading.Event) -> None:
        """Serve the bridge in real time until ``stop`` is set (then close the port)."""
        if self._master is None:
            self.open()
        period = 1.0 / self._settings.rate_hz
        next_tick = time.monotonic()
        try:
            while not stop.is_set():
                self._read_commands(max(0.0, next_tick - time.monotonic()))
                now = time.monotonic()
                if now < next_tick:
                    continue
                self._apply_faults(stop)
                self._tick(period, now)
                next_tick += period
                # After a stall (a disconnect, a slow machine) restart the clock, no burst.
                if now - next_tick > 5 * period:
                    next_tick = now + period
        finally:
            self.close()

    def _read_commands(self, timeout_s: float) -> None:
        if self._master is None:
            time.sleep(timeout_s)
            return
        ready, _, _ = select.select([self._master], [], [], timeout_s)
        if not ready:
            return
        try:
            data = os.read(self._master, 4096)
        except (BlockingIOError, OSError):
            return
        for decoded in self._decoder.feed(data):
            message = decoded.message
            if isinstance(message, CommandFrame):
                self._pwm_us = message.pwm_us
                if message.timeout_ms > 0:
                    self._command_timeout_s = message.timeout_ms / 1000.0
                self._last_command = time.monotonic()
                self.commands_received += 1

    def _apply_faults(self, stop: threading.Event) -> None:
        while True:
            try:
                fault = self._faults.get_nowait()
            except queue.Empty:
                return
            p = self._pending
            match fault:
                case Garbage(n_bytes):
                    self._write(self._rng.bytes(n_bytes))
                case CorruptCrc(n):
                    self._pending = replace(p, corrupt=p.corrupt + n)
                case Truncate(n):
                    self._pending = replace(p, truncate=p.truncate + n)
                case DuplicateFrame(n):
                    self._pending = replace(p, duplicate=p.duplicate + n)
                case OutOfRange(n):
                    self._pending = replace(p, out_of_range=p.out_of_range + n)
                case SkipSequence(n):
                    self._seq = (self._seq + n) % SEQ_MODULUS
                case ReplayFrames(back, count):
                    old = list(self._history)[-back:] if back > 0 else []
                    for frame in old[:count]:
                        self._write(frame)
                case BridgeReset():
                    self._seq = 0
                    self._boot = time.monotonic()
                    self._reset_pending = True
                case StuckLine(byte, duration_s):
                    self._stuck = (byte, time.monotonic() + duration_s)
                case Silence(duration_s):
                    self._silent_until = time.monotonic() + duration_s
                case SetCondition(condition):
                    self._sim.set_condition(condition)
                case Disconnect(duration_s):
                    self.close()
                    stop.wait(duration_s)
                    if not stop.is_set():
                        self.open()

    def _tick(self, period: float, now: float) -> None:
        self._timed_out = now - self._last_command > self._command_timeout_s
        if self._timed_out:
            self._pwm_us = NEUTRAL_PWM_US
        command = (self._pwm_us - NEUTRAL_PWM_US) / PWM_PER_UNIT
        sample = self._sim.step(command, period)
        self.last_sample = sample
        self._consumption_mah += abs(sample.current) * period / 3.6
        if now < self._silent_until:
            return
        if self._stuck is not None and now < self._stuck[1]:
            self._write(bytes([self._stuck[0]]) * round(_LINE_BYTES_PER_S * period))
            return
        p = self._pending
        voltage = _IMPLAUSIBLE_VOLTAGE_V if p.out_of_range else sample.voltage
        frame = self._encode(sample, voltage, now)
        copies = 2 if p.duplicate else 1
        if p.corrupt:
            frame = _corrupt(frame, _VOLTAGE_LOW_BYTE[self._settings.protocol])
        if p.truncate:
            frame = frame[: len(frame) // 2]
        self._pending = _Pending(
            corrupt=max(0, p.corrupt - 1),
            truncate=max(0, p.truncate - 1),
            duplicate=max(0, p.duplicate - 1),
            out_of_range=max(0, p.out_of_range - 1),
        )
        for _ in range(copies):
            self._write(frame)
        self._history.append(frame)
        self._reset_pending = False
        self._seq = (self._seq + 1) % SEQ_MODULUS
        self.frames_sent += 1

    def _encode(self, sample: Sample, voltage: float, now: float) -> bytes:
        if self._settings.protocol == "kiss":
            kiss = KissFrame(
                temperature_c=max(0.0, sample.temperature),
                voltage_v=voltage,
                current_a=abs(sample.current),
                consumption_mah=min(0xFFFF, int(self._consumption_mah)),
                rpm=abs(sample.rpm),
            )
            return encode_kiss(kiss, self._settings.pole_pairs)
        status = StatusFlag.ESC_TIMEOUT if self._timed_out else StatusFlag(0)
        if self._reset_pending:
            status |= StatusFlag.RESET
        frame = TelemetryFrame(
            timestamp_us=int(max(0.0, now - self._boot) * 1e6) % (1 << 32),
            pwm_us=self._pwm_us,
            voltage_v=voltage,
            current_a=sample.current,
            rpm=sample.rpm,
            temperature_c=sample.temperature,
            status=int(status),
        )
        return encode_telemetry(frame, self._seq)

    def _write(self, data: bytes) -> None:
        if self._master is None:
            return
        # A UART sends whether or not anyone listens: a full pty buffer drops the frame.
        with contextlib.suppress(BlockingIOError, OSError):
            os.write(self._master, data)


def _corrupt(frame: bytes, index: int) -> bytes:
    data = bytearray(frame)
    data[index] ^= 0x40
    return bytes(data)
