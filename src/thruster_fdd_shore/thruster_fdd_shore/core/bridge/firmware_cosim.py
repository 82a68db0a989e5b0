"""Co-simulation of the bridge firmware, ROS-free: the real ``firmware/`` on an emulated AVR.

The ATmega328P runs the built hex in avr8js (``firmware/cosim/runner.js``, a Node process) at
16 MHz, cycle by cycle, in virtual time paced to the wall clock. A :class:`FirmwareBridge` wires
it to the outside world:

* its USART0 to a pseudo-terminal (``os.openpty``, published under a stable symlink), which the
  ESC driver opens like a USB serial adapter;
* its servo pin, measured pulse by pulse, to the command of a :class:`ThrusterSimulator`,
  stepped every ``tick_s`` of virtual time;
* the simulator's readings back to the firmware's ESC telemetry pin, as HoTT replies to its
  polls (or periodic KISS frames), sent bit by bit by the runner's model ESC.

Faults are injected on request (line noise, a corrupted or implausible ESC frame, a silent ESC,
a main loop that hangs), and what happened is kept with virtual time stamps (pulses, ESC frames
served, host bytes delivered, frames the bridge sent, resets), which is how the tests check the
firmware. :func:`measure_loop_time` runs an image unpaced under load and reports its slowest
main-loop pass.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import queue
import select
import shutil
import struct
import subprocess
import threading
import time
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from thruster_fdd.core.bridge.kiss import KissDecoder, KissFrame, encode_kiss
from thruster_fdd.core.bridge.tfdd import (
    CommandFrame,
    DecodedFrame,
    FrameDecoder,
    encode_command,
    encode_version_query,
)
from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.core.bridge import hott
from thruster_fdd_shore.core.bridge.firmware_build import VARIANTS, FirmwareImage, firmware_dir
from thruster_fdd_shore.core.bridge.pty_link import PtyLink
from thruster_fdd_shore.core.sim.physics import Sample, ThrusterSimulator

CPU_HZ = 16_000_000
"""Clock of the emulated ATmega328P, Hz."""
NEUTRAL_PWM_US = 1500
PWM_PER_UNIT = 400.0
SIGNAL_LOST_S = 0.1
"""An ESC that sees no servo pulse for this long stops the motor (command 0)."""
IMPLAUSIBLE_VOLTAGE_V = 100.0
"""Voltage an ``ImplausibleEscFrame`` reports: on the wire, but above the 60 V limit."""
HISTORY = 20_000
"""Entries kept of each observation (pulses, frames, ...)."""

# Runner <-> parent messages: [u8 type][u32 length][payload] (runner.js has the layouts).
_MSG_UART_TX, _MSG_PULSES, _MSG_TICK, _MSG_RX_DONE = 0x01, 0x02, 0x03, 0x04
_MSG_ESC_SENT, _MSG_RESET, _MSG_STATS, _MSG_POLL = 0x05, 0x06, 0x07, 0x08
_CMD_UART_RX, _CMD_ESC_FRAME, _CMD_ESC_MUTE, _CMD_HANG = 0x11, 0x12, 0x13, 0x14
_CMD_GO, _CMD_STOP = 0x15, 0x16
_HEADER = struct.Struct("<BI")
# Where a CorruptEscFrame flips a bit: the voltage's low byte (0.4 V in HoTT, 0.04 V in KISS),
# so the value stays plausible and only the checksum can catch it.
_CORRUPT_AT = {"hott": 6, "kiss": 2}


@dataclass(frozen=True)
class CosimSettings:
    """How the co-simulated bridge is built and run.

    Attributes
    ----------
    telemetry_hz : int
        Telemetry frames per second the firmware sends, 10..100 (written to its EEPROM).
    servo_hz : int
        Servo frame rate, 50..400 Hz (EEPROM).
    pole_pairs : int
        Motor pole pairs, to turn rpm into the eRPM of KISS frames (the firmware assumes 7).
    tick_s : float
        Virtual time between two simulator steps, s.
    hott_first_byte_us, hott_byte_us : float
        HoTT reply timing of the model ESC: delay from the request to the first byte, and from
        one byte's start to the next, µs.
    kiss_period_s : float
        Interval of the model ESC's KISS frames, s.
    """

    telemetry_hz: int = 50
    servo_hz: int = 50
    pole_pairs: int = 7
    tick_s: float = 0.01
    hott_first_byte_us: float = 4000.0
    hott_byte_us: float = 1200.0
    kiss_period_s: float = 0.02

    def __post_init__(self) -> None:
        if isinstance(self.telemetry_hz, bool) or not isinstance(self.telemetry_hz, int):
            raise BadInputError(
                f"telemetry_hz must be a whole number of Hz, got {self.telemetry_hz}"
            )
        if not 10 <= self.telemetry_hz <= 100:
            raise BadInputError(
                f"the firmware's telemetry rate is 10..100 Hz, got {self.telemetry_hz}"
            )
        if not 50 <= self.servo_hz <= 400:
            raise BadInputError(f"the firmware's servo rate is 50..400 Hz, got {self.servo_hz}")
        if not 1 <= self.pole_pairs <= 255:
            raise BadInputError(f"pole_pairs must be within 1..255, got {self.pole_pairs}")
        if not 0.001 <= self.tick_s <= 0.1:
            raise BadInputError(f"tick_s must be within 0.001..0.1 s, got {self.tick_s}")
        if self.hott_byte_us < 1e6 * 10 / hott.BAUD:
            raise BadInputError(f"hott_byte_us {self.hott_byte_us} is shorter than one byte")


def eeprom_config(telemetry_hz: int, servo_hz: int) -> bytes:
    """The firmware's rate block at EEPROM address 0 (layout in ``firmware/src/main.c``).

    ``'T' 'B'``, telemetry rate (u8, Hz), servo rate (u16 LE, Hz), then a check byte that makes
    the six bytes sum to 0xFF mod 256. Flash it with avrdude to set a real bridge's rates.
    """
    body = b"TB" + bytes([telemetry_hz]) + servo_hz.to_bytes(2, "little")
    return body + bytes([(0xFF - sum(body)) & 0xFF])


@dataclass(frozen=True)
class CosimStats:
    """Progress of a co-simulation run.

    Attributes
    ----------
    virtual_s : float
        Virtual (AVR) time simulated, s.
    wall_s : float
        Wall-clock time since the run started, s.
    busy_s : float
        Wall-clock time the runner spent simulating (the rest it waited for the clock), s.
    loop_max_cycles : int
        Longest main-loop pass seen, CPU cycles (interrupts included).
    loops : int
        Main-loop passes.
    slips : int
        Episodes in which the runner fell more than 0.2 s behind the wall clock and gave up
        the rest of its backlog (virtual time then lags the wall clock: see ``speed``).
    stack_bytes : int
        Deepest stack seen, bytes below RAMEND (0 unless the run tracked it).
    """

    virtual_s: float = 0.0
    wall_s: float = 0.0
    busy_s: float = 0.0
    loop_max_cycles: int = 0
    loops: int = 0
    slips: int = 0
    stack_bytes: int = 0

    @property
    def speed(self) -> float:
        """Virtual seconds per wall-clock second (1.0 when paced and keeping up)."""
        return self.virtual_s / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def headroom(self) -> float:
        """Virtual seconds per second of simulating: how fast it could run unpaced."""
        return self.virtual_s / self.busy_s if self.busy_s > 0 else 0.0

    @property
    def loop_max_us(self) -> float:
        """Longest main-loop pass, µs."""
        return self.loop_max_cycles * 1e6 / CPU_HZ


@dataclass(frozen=True)
class Pulse:
    """One servo pulse the firmware produced: rising edge (virtual s) and width (µs)."""

    t: float
    width_us: float


@dataclass(frozen=True)
class ServedFrame:
    """An ESC frame handed to the model ESC.

    Attributes
    ----------
    frame_id : int
        Its id (increasing).
    sample : Sample
        The simulator sample it was made from.
    reading : hott.HottEscFrame or KissFrame
        Its values as they are on the wire (before any corruption).
    data : bytes
        The bytes sent (corrupted when ``fault`` is ``corrupt``).
    fault : str
        ``""``, ``"corrupt"`` (checksum broken) or ``"implausible"`` (voltage out of range).
    t_sent : float or None
        Virtual time the ESC started sending it; None if it never was (a newer frame won).
    """

    frame_id: int
    sample: Sample
    reading: hott.HottEscFrame | KissFrame
    data: bytes
    fault: str = ""
    t_sent: float | None = None


@dataclass(frozen=True)
class HostChunk:
    """Bytes written towards the firmware's USART0.

    Attributes
    ----------
    chunk_id : int
        Its id (increasing).
    data : bytes
        The bytes.
    noise : bool
        Injected line noise rather than bytes from the pty.
    t_received : float or None
        Virtual time its last byte reached the USART (None: not yet).
    dropped : bool
        Lost because the USART's receiver was off (the AVR was booting).
    """

    chunk_id: int
    data: bytes
    noise: bool = False
    t_received: float | None = None
    dropped: bool = False


@dataclass(frozen=True)
class BridgeFrame:
    """A frame the firmware sent to the host, decoded, with the virtual time of its first byte."""

    t: float
    frame: DecodedFrame


@dataclass(frozen=True)
class HostNoise:
    """``n_bytes`` random bytes on the host link: into the firmware, or out to the driver."""

    n_bytes: int = 64
    to_bridge: bool = True


@dataclass(frozen=True)
class CorruptEscFrame:
    """The ESC's next ``n_frames`` replies have one bit flipped (the checksum fails)."""

    n_frames: int = 1


@dataclass(frozen=True)
class ImplausibleEscFrame:
    """The ESC's next ``n_frames`` replies report 100 V, with a valid checksum."""

    n_frames: int = 1


@dataclass(frozen=True)
class EscSilence:
    """The ESC does not answer for ``duration_s`` of virtual time."""

    duration_s: float = 1.0


@dataclass(frozen=True)
class HangMainLoop:
    """The firmware's main loop stops at its entry (interrupts keep running) until the AVR
    watchdog resets the chip; the restarted firmware runs normally."""


@dataclass(frozen=True)
class SetCondition:
    """Change the simulated thruster's condition (fault onset), keeping its state."""

    condition: str


Fault = HostNoise | CorruptEscFrame | ImplausibleEscFrame | EscSilence | HangMainLoop | SetCondition


def _runner_command(image: FirmwareImage, options: dict[str, object]) -> list[str]:
    node = shutil.which("node")
    if node is None:
        raise FileNotFoundError("the co-simulation needs Node.js: no 'node' on PATH")
    folder = firmware_dir()
    if not (folder / "node_modules" / "avr8js").is_dir():
        raise FileNotFoundError(f"avr8js is not installed: run 'npm ci' in {folder}")
    full = {"hex": str(image.hex_path), "esc": image.variant, "loopAddress": image.loop_address}
    return [node, str(folder / "cosim" / "runner.js"), json.dumps(full | options)]


def _message(kind: int, payload: bytes = b"") -> bytes:
    return _HEADER.pack(kind, len(payload)) + payload


def _parse(buffer: bytearray) -> list[tuple[int, bytes]]:
    """Take every complete runner message off the front of ``buffer``."""
    out = []
    while len(buffer) >= _HEADER.size:
        kind, length = _HEADER.unpack_from(buffer)
        end = _HEADER.size + length
        if len(buffer) < end:
            break
        out.append((kind, bytes(buffer[_HEADER.size : end])))
        del buffer[:end]
    return out


def _stats(payload: bytes) -> CosimStats:
    return CosimStats(*struct.unpack("<dddIIII", payload))


class FirmwareBridge:
    """A simulated thruster behind the bridge firmware, on a pseudo-terminal.

    Parameters
    ----------
    simulator : ThrusterSimulator
        The thruster; stepped by the virtual time between two runner ticks.
    link : str or Path
        Path of the symlink to the pty's slave device: the port name the driver opens.
    image : FirmwareImage
        The built firmware (its variant sets HoTT or KISS ESC telemetry).
    settings : CosimSettings
        Rates and model-ESC timing.
    seed : int
        Seed of the injected noise bytes.
    """

    def __init__(
        self,
        simulator: ThrusterSimulator,
        link: str | Path,
        image: FirmwareImage,
        settings: CosimSettings | None = None,
        *,
        seed: int = 0,
    ) -> None:
        if image.variant not in VARIANTS:
            raise ValueError(f"unknown firmware variant {image.variant!r}")
        self._sim = simulator
        self._link = Path(link)
        self._image = image
        self._settings = settings or CosimSettings()
        self._rng = np.random.default_rng(seed)
        self._faults: queue.SimpleQueue[Fault] = queue.SimpleQueue()
        self._proc: subprocess.Popen[bytes] | None = None
        self._pty: PtyLink | None = None
        self._master: int | None = None
        self._inbox = bytearray()
        self._decoder = FrameDecoder()
        self._last_tick: float | None = None
        self._next_frame_id = 0
        self._next_chunk_id = 0
        self._consumption_mah = 0.0
        self._once: deque[str] = deque()
        self._once_in_flight: int | None = None
        self._served: dict[int, ServedFrame] = {}
        self._chunks: dict[int, HostChunk] = {}
        self.pulses: deque[Pulse] = deque(maxlen=HISTORY)
        self.frames: deque[BridgeFrame] = deque(maxlen=HISTORY)
        self.polls: deque[tuple[float, bytes]] = deque(maxlen=HISTORY)
        self.resets: list[tuple[float, int]] = []
        self.stats = CosimStats()
        self.last_sample: Sample | None = None

    @property
    def link(self) -> Path:
        """The port name the driver opens."""
        return self._link

    @property
    def virtual_time(self) -> float:
        """Virtual time of the last runner tick, s."""
        return self._last_tick or 0.0

    def served(self) -> list[ServedFrame]:
        """The ESC frames handed to the model ESC, oldest first (the last ``HISTORY``)."""
        return list(self._served.values())

    def chunks(self) -> list[HostChunk]:
        """The byte chunks written towards the firmware, oldest first (the last ``HISTORY``)."""
        return list(self._chunks.values())

    def open(self) -> str:
        """Create the pty, point the link at it and start the runner (not yet running);
        returns the slave device path.

        Raises
        ------
        FileNotFoundError
            Without Node.js or the runner's avr8js install.
        """
        options = {
            "eeprom": list(eeprom_config(self._settings.telemetry_hz, self._settings.servo_hz)),
            "realtime": True,
            "tickS": self._settings.tick_s,
            "hott": {
                "firstByteUs": self._settings.hott_first_byte_us,
                "byteUs": self._settings.hott_byte_us,
            },
            "kissPeriodS": self._settings.kiss_period_s,
        }
        command = _runner_command(self._image, options)
        self._pty = PtyLink.open(self._link)
        self._master = self._pty.master
        self._proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        return self._pty.device

    def close(self) -> None:
        """Stop the runner, remove the link and close the pty."""
        if self._proc is not None:
            with contextlib.suppress(OSError):
                self._send(_CMD_STOP)
            try:
                self._proc.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
            self._drain_runner()
            self._proc = None
        if self._pty is not None:
            self._pty.close()
        self._pty = None
        self._master = None

    def inject(self, fault: Fault) -> None:
        """Queue a fault; it takes effect within one pass of :meth:`run`. Thread-safe."""
        self._faults.put(fault)

    def run(self, stop: threading.Event) -> None:
        """Run the co-simulation until ``stop`` is set or the runner exits (then close).

        Raises
        ------
        RuntimeError
            If the runner failed (its error is on stderr).
        """
        if self._proc is None:
            self.open()
        proc = self._proc
        runner_out = proc.stdout.fileno()
        self._send(_CMD_GO)
        try:
            while not stop.is_set() and proc.poll() is None:
                self._apply_faults()
                ready, _, _ = select.select([runner_out, self._master], [], [], 0.05)
                if self._master in ready:
                    with contextlib.suppress(BlockingIOError, OSError):
                        self._to_bridge(os.read(self._master, 4096), noise=False)
                if runner_out in ready:
                    data = os.read(runner_out, 1 << 16)
                    if not data:
                        break
                    self._inbox += data
                    for kind, payload in _parse(self._inbox):
                        self._handle(kind, payload)
        finally:
            self.close()
        if not stop.is_set() and proc.returncode:
            raise RuntimeError(f"the co-simulation runner exited with code {proc.returncode}")

    # ---- runner I/O ------------------------------------------------------------------------

    def _send(self, kind: int, payload: bytes = b"") -> None:
        self._proc.stdin.write(_message(kind, payload))
        self._proc.stdin.flush()

    def _drain_runner(self) -> None:
        """Take the stopped runner's last statistics from its pipe."""
        self._inbox += self._proc.stdout.read()
        for kind, payload in _parse(self._inbox):
            if kind == _MSG_STATS:
                self.stats = _stats(payload)

    def _to_bridge(self, data: bytes, *, noise: bool) -> None:
        chunk = HostChunk(self._next_chunk_id, data, noise)
        self._next_chunk_id += 1
        self._remember(self._chunks, chunk.chunk_id, chunk)
        self._send(_CMD_UART_RX, struct.pack("<Id", chunk.chunk_id, 0.0) + data)

    @staticmethod
    def _remember(store: dict, key: int, value: object) -> None:
        store[key] = value
        if len(store) > HISTORY:
            del store[next(iter(store))]

    def _handle(self, kind: int, payload: bytes) -> None:
        if kind == _MSG_UART_TX:
            (t,) = struct.unpack_from("<d", payload)
            data = payload[8:]
            for decoded in self._decoder.feed(data):
                self.frames.append(BridgeFrame(t, decoded))
            if self._master is not None:
                # A UART sends whether or not anyone listens: a full pty drops the bytes.
                with contextlib.suppress(BlockingIOError, OSError):
                    os.write(self._master, data)
        elif kind == _MSG_PULSES:
            for t, width in struct.iter_unpack("<df", payload):
                self.pulses.append(Pulse(t, width))
        elif kind == _MSG_TICK:
            self._on_tick(*struct.unpack("<dff", payload))
        elif kind == _MSG_RX_DONE:
            chunk_id, t, dropped = struct.unpack("<IdB", payload)
            if chunk_id in self._chunks:
                chunk = replace(self._chunks[chunk_id], t_received=t, dropped=bool(dropped))
                self._chunks[chunk_id] = chunk
        elif kind == _MSG_ESC_SENT:
            frame_id, t = struct.unpack("<Id", payload)
            if frame_id in self._served:
                self._served[frame_id] = replace(self._served[frame_id], t_sent=t)
            if frame_id == self._once_in_flight:
                self._once_in_flight = None
        elif kind == _MSG_RESET:
            t, cause = struct.unpack("<dB", payload)
            self.resets.append((t, cause))
        elif kind == _MSG_STATS:
            self.stats = _stats(payload)
        elif kind == _MSG_POLL:
            (t,) = struct.unpack_from("<d", payload)
            self.polls.append((t, payload[8:]))

    # ---- the thruster and its ESC ----------------------------------------------------------

    def _on_tick(self, t: float, width_us: float, age_s: float) -> None:
        dt = self._settings.tick_s if self._last_tick is None else max(0.0, t - self._last_tick)
        self._last_tick = t
        signal = math.isfinite(width_us) and math.isfinite(age_s) and age_s <= SIGNAL_LOST_S
        command = (width_us - NEUTRAL_PWM_US) / PWM_PER_UNIT if signal else 0.0
        sample = self._sim.step(min(1.0, max(-1.0, command)), dt)
        self.last_sample = sample
        self._consumption_mah += abs(sample.current) * dt / 3.6
        self._serve(sample, "", once=False)
        if self._once and self._once_in_flight is None:
            self._once_in_flight = self._serve(sample, self._once.popleft(), once=True)

    def _serve(self, sample: Sample, fault: str, *, once: bool) -> int:
        voltage = IMPLAUSIBLE_VOLTAGE_V if fault == "implausible" else sample.voltage
        # Neither protocol has a sign: the ESC reports magnitudes (current only while driving).
        current, rpm = max(0.0, sample.current), abs(sample.rpm)
        reading: hott.HottEscFrame | KissFrame
        if self._image.variant == "hott":
            capacity = min(self._consumption_mah, 655_350.0)
            data = hott.encode_esc_frame(
                hott.HottEscFrame(voltage, current, rpm, sample.temperature, capacity)
            )
            reading = hott.decode_esc_frame(data)
        else:
            kiss = KissFrame(
                max(0.0, sample.temperature),
                voltage,
                current,
                min(0xFFFF, int(self._consumption_mah)),
                rpm,
            )
            data = encode_kiss(kiss, self._settings.pole_pairs)
            reading = KissDecoder(self._settings.pole_pairs).feed(data)[0]
        if fault == "corrupt":
            flipped = bytearray(data)
            flipped[_CORRUPT_AT[self._image.variant]] ^= 0x04
            data = bytes(flipped)
        frame_id = self._next_frame_id
        self._next_frame_id += 1
        self._remember(self._served, frame_id, ServedFrame(frame_id, sample, reading, data, fault))
        self._send(_CMD_ESC_FRAME, struct.pack("<IB", frame_id, once) + data)
        return frame_id

    def _apply_faults(self) -> None:
        while True:
            try:
                fault = self._faults.get_nowait()
            except queue.Empty:
                return
            match fault:
                case HostNoise(n_bytes, to_bridge):
                    noise = self._rng.bytes(n_bytes)
                    if to_bridge:
                        self._to_bridge(noise, noise=True)
                    elif self._master is not None:
                        with contextlib.suppress(BlockingIOError, OSError):
                            os.write(self._master, noise)
                case CorruptEscFrame(n):
                    self._once.extend(["corrupt"] * n)
                case ImplausibleEscFrame(n):
                    self._once.extend(["implausible"] * n)
                case EscSilence(duration_s):
                    self._send(_CMD_ESC_MUTE, struct.pack("<d", duration_s))
                case HangMainLoop():
                    self._send(_CMD_HANG)
                case SetCondition(condition):
                    self._sim.set_condition(condition)


def measure_loop_time(image: FirmwareImage, seconds: float = 3.0, *, seed: int = 0) -> CosimStats:
    """Run ``image`` unpaced under load and return the run's statistics (worst loop pass).

    The load: telemetry at 100 Hz and servo frames at 400 Hz (the most interrupts), a command
    frame every 50 ms (one in four clamped), a version query every 250 ms, 64 bytes of line
    noise every 500 ms, and the model ESC answering every poll (HoTT) or every 20 ms (KISS).

    Parameters
    ----------
    image : FirmwareImage
        The firmware to time.
    seconds : float
        Virtual time to simulate, s.
    seed : int
        Seed of the noise bytes.

    Returns
    -------
    CosimStats
        ``loop_max_us`` is the slowest main-loop pass, interrupts included; ``stack_bytes`` the
        deepest stack.
    """
    options = {
        "eeprom": list(eeprom_config(100, 400)),
        "realtime": False,
        "durationS": seconds,
        "trackStack": True,
    }
    rng = np.random.default_rng(seed)
    reading = hott.HottEscFrame(15.0, 3.2, 2500.0, 25.0, 120.0)
    if image.variant == "hott":
        esc_frame = hott.encode_esc_frame(reading)
    else:
        esc_frame = encode_kiss(KissFrame(25.0, 15.0, 3.2, 120, 2500.0))
    traffic: list[tuple[float, bytes]] = []
    for k in range(int(seconds / 0.05)):
        pulse = 2000 if k % 4 == 3 else 1300 + 400 * (k % 2)
        command = encode_command(CommandFrame(pulse, 500), k % 65536)
        traffic.append((0.05 * k, command))
        if k % 5 == 0:
            traffic.append((0.05 * k + 0.01, encode_version_query(k % 65536)))
        if k % 10 == 0:
            traffic.append((0.05 * k + 0.02, rng.bytes(64)))
    proc = subprocess.Popen(
        _runner_command(image, options), stdin=subprocess.PIPE, stdout=subprocess.PIPE
    )
    messages = [_message(_CMD_ESC_FRAME, struct.pack("<IB", 0, 0) + esc_frame)]
    for i, (t, data) in enumerate(traffic):
        messages.append(_message(_CMD_UART_RX, struct.pack("<Id", i, t) + data))
    messages.append(_message(_CMD_GO))
    proc.stdin.write(b"".join(messages))
    proc.stdin.flush()
    # The runner stops by itself after `seconds`; the deadline only bounds a broken one.
    deadline = time.monotonic() + 60.0 + 30.0 * seconds
    out = bytearray()
    stats = CosimStats()
    fd = proc.stdout.fileno()
    while (left := deadline - time.monotonic()) > 0:
        if not select.select([fd], [], [], left)[0]:
            continue
        data = os.read(fd, 1 << 16)
        if not data:
            break
        out += data
        for kind, payload in _parse(out):
            if kind == _MSG_STATS:
                stats = _stats(payload)
    proc.kill()
    proc.wait()
    proc.stdin.close()
    proc.stdout.close()
    return stats
