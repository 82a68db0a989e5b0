"""Check a bridge on a serial port, without ROS: the first thing to run on a flashed bridge.

``python -m thruster_fdd_shore.core.bridge.bridge_check /dev/ttyUSB0 [--pulse 1550] [--seconds 3]``

Asks for the firmware version, reads telemetry for a while and reports its rate, lost frames,
the status flags seen and the last reading. With ``--pulse`` it also commands that pulse for the
whole time (bench test: propeller off or thruster in water) and checks the bridge echoes it, then
sends neutral. Exit code 0 when the bridge looks healthy, 1 with the problems listed, 2 when the
port cannot be opened or the options are bad.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

import serial

from thruster_fdd.core.bridge.tfdd import (
    CommandFrame,
    DecoderStats,
    FrameDecoder,
    StatusFlag,
    TelemetryFrame,
    VersionFrame,
    classify_seq,
    encode_command,
    encode_version_query,
)

COMMAND_PERIOD_S = 0.05
"""Interval of the command frames during a check, s (the driver's 20 Hz)."""
BRIDGE_TIMEOUT_MS = 500
"""The bridge watchdog sent with every command, ms."""


@dataclass(frozen=True)
class CheckReport:
    """What a check saw.

    Attributes
    ----------
    version : VersionFrame or None
        The firmware's answer to a version query; None without one.
    frames : int
        Telemetry frames received.
    seconds : float
        Length of the check, s.
    lost : int
        Telemetry frames missing from the sequence numbers.
    flags_seen : int
        ``StatusFlag`` bits set in any frame.
    last : TelemetryFrame or None
        The last telemetry frame.
    pulse_us : int or None
        The pulse commanded, µs (None: none was).
    echoed : int
        Frames that echoed the commanded pulse.
    decoder : DecoderStats
        The frame decoder's counters (CRC errors, noise, ...).
    """

    version: VersionFrame | None
    frames: int
    seconds: float
    lost: int
    flags_seen: int
    last: TelemetryFrame | None
    pulse_us: int | None
    echoed: int
    decoder: DecoderStats

    def problems(self, rate_hz: float) -> tuple[str, ...]:
        """What is wrong for a bridge expected to send ``rate_hz`` frames a second."""
        found = []
        if self.version is None:
            found.append("no answer to the version query")
        rate = self.frames / self.seconds if self.seconds > 0 else 0.0
        if rate < 0.8 * rate_hz:
            found.append(f"telemetry {rate:.1f} Hz, expected {rate_hz:g} Hz")
        if self.lost or self.decoder.crc_errors or self.decoder.truncated:
            found.append(
                f"{self.lost} frames lost, {self.decoder.crc_errors} CRC errors, "
                f"{self.decoder.truncated} truncated"
            )
        faults = StatusFlag.ADC_FAULT | StatusFlag.RPM_FAULT
        if self.last is not None and self.last.status & faults:
            flags = StatusFlag(self.last.status & faults).name
            found.append(f"the ESC's telemetry is not valid ({flags})")
        if self.pulse_us is not None and self.echoed == 0:
            found.append(f"the commanded {self.pulse_us} µs pulse was never applied")
        return tuple(found)


def check_bridge(
    port: str, *, seconds: float = 3.0, pulse_us: int | None = None, baud: int = 115200
) -> CheckReport:
    """Talk to the bridge on ``port`` for ``seconds`` s (see the module docstring).

    Raises
    ------
    serial.SerialException
        If the port cannot be opened.
    ValueError
        If ``pulse_us`` is outside the protocol's 1000..2000 µs.
    """
    if pulse_us is not None:
        encode_command(CommandFrame(pulse_us, BRIDGE_TIMEOUT_MS), 0)
    decoder = FrameDecoder()
    version = last = None
    frames = lost = flags = echoed = 0
    prev_seq: int | None = None
    seq = 0
    with serial.Serial(port, baud, timeout=COMMAND_PERIOD_S) as link:
        # Bytes buffered before the port was opened end in a gap (a full buffer drops the rest):
        # the check measures the live stream only.
        link.reset_input_buffer()
        link.write(encode_version_query(seq))
        start = time.monotonic()
        while (now := time.monotonic()) - start < seconds:
            if pulse_us is not None:
                seq = (seq + 1) % 65536
                command = CommandFrame(pulse_us, BRIDGE_TIMEOUT_MS)
                link.write(encode_command(command, seq))
            for decoded in decoder.feed(link.read(4096)):
                # The bridge numbers every frame it sends, version replies too (docs/protocol.md).
                if prev_seq is not None:
                    lost += classify_seq(prev_seq, decoded.seq).lost
                prev_seq = decoded.seq
                message = decoded.message
                if isinstance(message, VersionFrame):
                    version = message
                elif isinstance(message, TelemetryFrame):
                    frames += 1
                    flags |= message.status
                    if pulse_us is not None and message.pwm_us == pulse_us:
                        echoed += 1
                    last = message
        if pulse_us is not None:
            link.write(encode_command(CommandFrame(1500, BRIDGE_TIMEOUT_MS), 0))
    return CheckReport(
        version, frames, now - start, lost, flags, last, pulse_us, echoed, decoder.stats()
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Run a check and print its report; see the module docstring for the exit codes."""
    parser = argparse.ArgumentParser(
        prog="python -m thruster_fdd_shore.core.bridge.bridge_check", description=__doc__
    )
    parser.add_argument("port", help="serial port of the bridge, e.g. /dev/ttyUSB0")
    parser.add_argument("--seconds", type=float, default=3.0, help="length of the check, s")
    parser.add_argument("--rate", type=float, default=50.0, help="expected telemetry rate, Hz")
    parser.add_argument("--pulse", type=int, help="command this pulse, µs (1000..2000)")
    args = parser.parse_args(argv)
    try:
        report = check_bridge(args.port, seconds=args.seconds, pulse_us=args.pulse)
    except (serial.SerialException, ValueError) as exc:
        print(f"bridge_check: error: {exc}", file=sys.stderr)
        return 2
    v = report.version
    print(f"firmware: {f'{v.major}.{v.minor}.{v.patch}' if v else 'no answer'}")
    print(
        f"telemetry: {report.frames} frames in {report.seconds:.1f} s, {report.lost} lost, "
        f"flags seen: {StatusFlag(report.flags_seen).name or 'none'}"
    )
    if report.last is not None:
        f = report.last
        print(
            f"last: pulse {f.pwm_us} µs, {f.voltage_v:.2f} V, {f.current_a:.2f} A, "
            f"{f.rpm:.0f} rpm, {f.temperature_c:.2f} °C, status {f.status:#04x}"
        )
    problems = report.problems(args.rate)
    for problem in problems:
        print(f"problem: {problem}")
    print("bridge OK" if not problems else "bridge NOT OK")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
