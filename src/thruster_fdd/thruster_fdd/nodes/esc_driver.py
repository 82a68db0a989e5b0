"""ESC driver node: one thruster's serial bridge <-> ROS.

Reads telemetry frames from the bridge with pyserial (tfdd protocol or KISS ESC telemetry),
publishes ``EscTelemetry`` on ``esc/telemetry``, forwards ``ThrusterCommand`` from
``esc/command`` as command frames (clamped, rate-limited, neutral when commands stop), and
reports the link on ``/diagnostics``.

Serial reads happen on a reader thread that blocks on the port and wakes the executor through a
guard condition, so the executor is never blocked by I/O; the thread re-opens a lost port.
"""

from __future__ import annotations

import contextlib
import queue
import threading
from dataclasses import dataclass
from typing import Any

import serial
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from thruster_fdd_msgs.msg import EscTelemetry, ThrusterCommand

from thruster_fdd.core.bridge.kiss import KissDecoder, KissFrame
from thruster_fdd.core.bridge.link import (
    LinkWindow,
    assess_link,
    clamp_command,
    command_to_pwm,
    frame_stamps,
    pwm_to_command,
    slew,
)
from thruster_fdd.core.bridge.plausibility import TelemetrySample, check_telemetry, to_sample
from thruster_fdd.core.bridge.sequence import SeqCounts, SequenceWindow
from thruster_fdd.core.bridge.tfdd import (
    CommandFrame,
    DecodedFrame,
    DecoderStats,
    FrameDecoder,
    StatusFlag,
    TelemetryFrame,
    encode_command,
)
from thruster_fdd.nodes.common import (
    NO_PUB_EVENTS,
    NO_SUB_EVENTS,
    RELIABLE_10,
    declare_parameters,
    diagnostics_publisher,
    publish_status,
    run,
    status_name,
)

# (name, default, description) of every parameter; the README's table is made from the same.
PARAMETERS: tuple[tuple[str, object, str], ...] = (
    ("thruster_id", "t0", "thruster id written into every message"),
    ("port", "/dev/ttyUSB0", "serial port of the bridge (a device or a symlink to one)"),
    ("baud", 115200, "serial baud rate, bit/s"),
    ("protocol", "tfdd", "telemetry format: tfdd (bridge protocol) or kiss (KISS/BLHeli_32)"),
    ("rate_hz", 50.0, "telemetry rate the bridge sends, Hz (for rate and staleness checks)"),
    ("pole_pairs", 7, "motor pole pairs, to turn KISS eRPM into rpm"),
    ("command_rate_hz", 20.0, "rate at which command frames are sent to the bridge, Hz"),
    ("command_timeout_s", 0.5, "watchdog: no esc/command for this long -> neutral, s"),
    ("max_command_rate_per_s", 4.0, "slew limit of the command, 1/s (0 disables)"),
    ("bridge_timeout_ms", 500, "the bridge's own watchdog sent in every command frame, ms"),
    ("reconnect_period_s", 0.25, "time between attempts to re-open a lost port, s"),
    ("diagnostics_period_s", 1.0, "period of the /diagnostics status, s"),
)


@dataclass(frozen=True)
class _Received:
    """A decoded frame and the host time it arrived."""

    frame: DecodedFrame | KissFrame
    stamp_ns: int


def _mcu_time_us(frame: DecodedFrame | KissFrame) -> int | None:
    if isinstance(frame, DecodedFrame) and isinstance(frame.message, TelemetryFrame):
        return frame.message.timestamp_us
    return None


class EscDriver(Node):
    """The ESC driver of one thruster (see module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("esc_driver", **node_kwargs)
        declare_parameters(self, PARAMETERS)
        p = self.get_parameter
        self._id = p("thruster_id").value
        self._port = p("port").value
        self._baud = int(p("baud").value)
        self._protocol = p("protocol").value
        if self._protocol not in ("tfdd", "kiss"):
            raise ValueError(f"parameter protocol must be 'tfdd' or 'kiss', got {self._protocol!r}")
        self._rate_hz = float(p("rate_hz").value)
        self._pole_pairs = int(p("pole_pairs").value)
        self._command_timeout_s = float(p("command_timeout_s").value)
        self._max_rate = float(p("max_command_rate_per_s").value)
        self._bridge_timeout_ms = int(p("bridge_timeout_ms").value)
        self._reconnect_s = float(p("reconnect_period_s").value)
        self._diag_period_s = float(p("diagnostics_period_s").value)

        self._pub = self.create_publisher(
            EscTelemetry, "esc/telemetry", qos_profile_sensor_data, event_callbacks=NO_PUB_EVENTS
        )
        self._diag_pub = diagnostics_publisher(self)
        self.create_subscription(
            ThrusterCommand,
            "esc/command",
            self._on_command,
            RELIABLE_10,
            event_callbacks=NO_SUB_EVENTS,
        )

        self._inbox: queue.SimpleQueue[_Received] = queue.SimpleQueue()
        self._wake = self.create_guard_condition(self._drain)
        self._serial: serial.Serial | None = None
        self._serial_lock = threading.Lock()
        self._port_error = "not opened yet"
        self._reconnects = 0
        self._stop = threading.Event()

        # Command state (executor thread only).
        self._target = 0.0
        self._applied = 0.0
        self._last_command_ns: int | None = None
        self._last_send_ns = self.get_clock().now().nanoseconds
        self._tx_seq = 0
        self._watchdog = True

        # Telemetry state (executor thread only).
        self._sequence = SequenceWindow()
        self._kiss_seq = 0
        self._last_frame_ns: int | None = None
        self._counts = {"frames": 0, "rejected": 0}
        self._reject_reason = ""
        self._bridge_faults = ""
        self._flags_pending = 0
        self._decoder_stats = DecoderStats()
        self._window_start = (dict(self._counts), DecoderStats(), SeqCounts())

        self._reader = threading.Thread(target=self._read_loop, name="esc-serial", daemon=True)
        self._reader.start()
        self.create_timer(1.0 / float(p("command_rate_hz").value), self._send_command)
        self.create_timer(self._diag_period_s, self._publish_diagnostics)
        self.get_logger().info(
            f"thruster {self._id}: {self._protocol} telemetry on {self._port} "
            f"at {self._baud} baud, expecting {self._rate_hz:g} Hz"
        )

    # ---- serial side (reader thread) -------------------------------------------------------

    def _read_loop(self) -> None:
        decoder: FrameDecoder | KissDecoder = (
            KissDecoder(self._pole_pairs) if self._protocol == "kiss" else FrameDecoder()
        )
        while not self._stop.is_set():
            port = self._serial
            if port is None:
                self._open_port()
                continue
            try:
                data = port.read(max(1, port.in_waiting))
            except (serial.SerialException, OSError, TypeError) as exc:
                # TypeError: pyserial reading a port closed under it by _close_port.
                self._close_port(f"read failed: {exc}")
                continue
            if not data:
                continue
            stamp = self.get_clock().now().nanoseconds
            frames = decoder.feed(data)
            self._decoder_stats = decoder.stats()
            for frame, frame_stamp in zip(
                frames, frame_stamps(stamp, [_mcu_time_us(f) for f in frames]), strict=True
            ):
                self._inbox.put(_Received(frame, frame_stamp))
            if frames:
                self._wake.trigger()

    def _open_port(self) -> None:
        try:
            port = serial.Serial(self._port, self._baud, timeout=0.1, write_timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._port_error = f"{self._port}: {exc}"
            self._stop.wait(self._reconnect_s)
            return
        with self._serial_lock:
            self._serial = port
        if self._port_error != "not opened yet":
            self._reconnects += 1
            self.get_logger().info(f"re-opened {self._port}")
        self._port_error = ""

    def _close_port(self, reason: str) -> None:
        with self._serial_lock:
            port, self._serial = self._serial, None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        self._port_error = f"{self._port}: {reason}"
        self.get_logger().warning(f"lost {self._port}: {reason}; retrying")

    # ---- telemetry (executor thread) -------------------------------------------------------

    def _drain(self) -> None:
        while True:
            try:
                received = self._inbox.get_nowait()
            except queue.Empty:
                return
            if isinstance(received.frame, KissFrame):
                self._handle_kiss(received.frame, received.stamp_ns)
            elif isinstance(received.frame.message, TelemetryFrame):
                self._handle_tfdd(received.frame.seq, received.frame.message, received.stamp_ns)

    def _handle_tfdd(self, seq: int, frame: TelemetryFrame, stamp_ns: int) -> None:
        reset = bool(frame.status & StatusFlag.RESET)
        decision = self._sequence.check(seq, reset, frame.timestamp_us)
        if not decision.publish:
            return
        if decision.lost:
            self._flags_pending |= EscTelemetry.SEQUENCE_GAP
        # ESC_TIMEOUT is the bridge's watchdog at work and RESET its restart, both reported
        # separately; the rest are faults.
        faults = StatusFlag(frame.status) & ~(StatusFlag.ESC_TIMEOUT | StatusFlag.RESET)
        self._bridge_faults = faults.name or "" if faults else ""
        sample = to_sample(frame)
        command = pwm_to_command(frame.pwm_us)
        self._publish(seq, sample, command, frame.pwm_us, stamp_ns, 0)

    def _handle_kiss(self, frame: KissFrame, stamp_ns: int) -> None:
        self._kiss_seq += 1
        # KISS carries no sign: the direction is the one the driver commands.
        sign = -1.0 if self._applied < 0 else 1.0
        sample = to_sample(frame)
        sample = TelemetrySample(
            voltage_v=sample.voltage_v,
            current_a=sample.current_a,
            rpm=sign * (sample.rpm or 0.0),
            temperature_c=sample.temperature_c,
            consumption_mah=sample.consumption_mah,
        )
        pwm = command_to_pwm(self._applied)
        self._publish(
            self._kiss_seq, sample, self._applied, pwm, stamp_ns, EscTelemetry.NO_COMMAND_ECHO
        )

    def _publish(
        self,
        seq: int,
        sample: TelemetrySample,
        command: float,
        pwm_us: int,
        stamp_ns: int,
        flags: int,
    ) -> None:
        problems = check_telemetry(sample)
        if problems:
            self._counts["rejected"] += 1
            self._reject_reason = problems[0]
            return
        stats = self._decoder_stats
        window_stats = self._window_start[1]
        if stats.crc_errors > window_stats.crc_errors:
            flags |= EscTelemetry.CRC_ERRORS
        if self._watchdog:
            flags |= EscTelemetry.WATCHDOG_NEUTRAL
        if self._bridge_faults:
            flags |= EscTelemetry.BRIDGE_FAULT
        msg = EscTelemetry()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        msg.header.frame_id = self._id
        msg.thruster_id = self._id
        msg.sequence = seq % (1 << 32)
        msg.command = float(command)
        msg.pwm_us = int(pwm_us)
        msg.voltage_v = float(sample.voltage_v or 0.0)
        msg.current_a = float(sample.current_a or 0.0)
        msg.rpm = float(sample.rpm or 0.0)
        msg.temperature_c = float(sample.temperature_c or 0.0)
        msg.status = flags | self._flags_pending
        self._flags_pending = 0
        self._pub.publish(msg)
        self._counts["frames"] += 1
        self._last_frame_ns = stamp_ns

    # ---- commands (executor thread) --------------------------------------------------------

    def _on_command(self, msg: ThrusterCommand) -> None:
        try:
            self._target = clamp_command(msg.command)
        except ValueError as exc:
            self.get_logger().warning(f"refused command: {exc}", throttle_duration_sec=1.0)
            return
        self._last_command_ns = self.get_clock().now().nanoseconds

    def _send_command(self) -> None:
        now = self.get_clock().now().nanoseconds
        self._watchdog = (
            self._last_command_ns is None
            or (now - self._last_command_ns) * 1e-9 > self._command_timeout_s
        )
        target = 0.0 if self._watchdog else self._target
        dt = (now - self._last_send_ns) * 1e-9
        self._last_send_ns = now
        self._applied = slew(self._applied, target, dt, self._max_rate)
        self._write_command(self._applied)

    def _write_command(self, command: float) -> None:
        frame = CommandFrame(command_to_pwm(command), self._bridge_timeout_ms)
        data = encode_command(frame, self._tx_seq)
        self._tx_seq = (self._tx_seq + 1) % 65536
        with self._serial_lock:
            port = self._serial
            if port is None:
                return
            with contextlib.suppress(serial.SerialException, OSError):
                port.write(data)

    # ---- diagnostics -----------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        start_counts, start_stats, start_seq = self._window_start
        stats = self._decoder_stats
        seq = self._sequence.counts()
        now = self.get_clock().now().nanoseconds
        since = None if self._last_frame_ns is None else (now - self._last_frame_ns) * 1e-9
        window = LinkWindow(
            period_s=self._diag_period_s,
            expected_rate_hz=self._rate_hz,
            port_open=self._serial is not None,
            port_error=self._port_error,
            frames=self._counts["frames"] - start_counts["frames"],
            crc_errors=stats.crc_errors - start_stats.crc_errors,
            truncated=stats.truncated - start_stats.truncated,
            garbage_bytes=stats.garbage_bytes - start_stats.garbage_bytes,
            lost=seq.lost - start_seq.lost,
            duplicates=seq.duplicates - start_seq.duplicates,
            replayed=seq.replayed - start_seq.replayed,
            resets=seq.resets - start_seq.resets,
            resyncs=seq.resyncs - start_seq.resyncs,
            stuck_low_bytes=stats.stuck_low_bytes - start_stats.stuck_low_bytes,
            stuck_high_bytes=stats.stuck_high_bytes - start_stats.stuck_high_bytes,
            rejected=self._counts["rejected"] - start_counts["rejected"],
            reject_reason=self._reject_reason,
            since_frame_s=since,
            watchdog_neutral=self._watchdog,
            bridge_faults=self._bridge_faults,
            reconnects=self._reconnects,
        )
        self._window_start = (dict(self._counts), stats, seq)
        health = assess_link(window)
        publish_status(
            self,
            self._diag_pub,
            health.level,
            status_name("esc", self._id),
            health.message,
            self._id,
            [("port", self._port), *health.values],
        )

    def shutdown(self) -> None:
        """Send neutral to the bridge, stop the reader thread and close the port."""
        self._write_command(0.0)
        self._stop.set()
        self._reader.join(timeout=1.0)
        with self._serial_lock:
            port, self._serial = self._serial, None
        if port is not None:
            port.close()


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C (``esc_driver --ros-args -p port:=/dev/ttyUSB0 ...``)."""
    run(EscDriver, args)


if __name__ == "__main__":
    main()
