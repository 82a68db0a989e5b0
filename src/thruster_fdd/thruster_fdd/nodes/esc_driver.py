"""ESC driver node: one thruster's serial bridge <-> ROS, as a managed (lifecycle) node.

Reads telemetry frames from the bridge with pyserial (tfdd protocol or KISS ESC telemetry),
publishes ``EscTelemetry`` on ``esc/telemetry``, forwards ``ThrusterCommand`` from
``esc/command`` as command frames (clamped, rate-limited, neutral when commands stop), and
reports the link and the newest published sample on ``/diagnostics``.

Lifecycle: *configure* reads the parameters (a bad one fails the transition, logged) and opens
the port (a port that cannot be opened yet is retried every ``reconnect_period_s`` and reported
as ERROR); *activate* publishes telemetry and forwards commands; *deactivate* sends neutral and
stops both (the link is still read and reported); *cleanup* closes the port; *shutdown* sends
neutral and closes. With ``autostart`` the node configures and activates itself when it starts
spinning; otherwise a lifecycle manager drives it (``thruster-fdd up`` does).

All drivers of a process share one reader thread (``core.bridge.ports``) that waits on every
port at once, decodes, and hands the frames to the executor with ``create_task`` (the
EventsExecutor has no guard conditions), so the executor never blocks on I/O. The same thread
sends the command frames at ``command_rate_hz``, the drivers of one rate in one wake (a ROS
timer per driver would wake the executor's timer thread and then the executor, once per driver
and period); the command state it shares with the executor's ``esc/command`` callback is
guarded by a lock.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import serialize_message
from thruster_fdd_msgs.msg import EscTelemetry, ThrusterCommand

from thruster_fdd.core.bridge.kiss import KissDecoder, KissFrame
from thruster_fdd.core.bridge.link import (
    ERROR,
    WARN,
    CommandWatchdog,
    LinkWindow,
    assess_link,
    command_to_pwm,
    frame_stamps,
    pwm_to_command,
)
from thruster_fdd.core.bridge.plausibility import TelemetrySample, check_telemetry, to_sample
from thruster_fdd.core.bridge.ports import SerialLink, SerialPorts
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
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.names import check_thruster_id
from thruster_fdd.nodes.common import (
    NO_PUB_EVENTS,
    NO_SUB_EVENTS,
    RELIABLE_10,
    Limit,
    RecordSink,
    declare_parameters,
    diagnostics_publisher,
    publish_recorded,
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
    ("autostart", False, "configure and activate at start, without a lifecycle manager"),
)

# Ranges and allowed values, in the descriptors (``ros2 param describe``, ``esc_driver --help``);
# ``DriverSettings`` checks every value against them again at configure (a value set after
# start, a rounding at the edge), and ``thruster-fdd up`` checks its driver settings against the
# same table before it starts anything. A bridge watchdog of 0 ms would stop every command.
LIMITS: dict[str, Limit] = {
    "baud": (1200, 4_000_000),
    "protocol": ("tfdd", "kiss"),
    "rate_hz": (0.1, 10_000.0),
    "pole_pairs": (1, 100),
    "command_rate_hz": (0.1, 1000.0),
    "command_timeout_s": (0.01, 60.0),
    "max_command_rate_per_s": (0.0, 1000.0),
    "bridge_timeout_ms": (1, 65535),
    "reconnect_period_s": (0.01, 60.0),
    "diagnostics_period_s": (0.01, 3600.0),
}

SAMPLE_FORMATS: tuple[tuple[str, str], ...] = (
    ("command", ".2f"),
    ("pwm_us", "d"),
    ("voltage_v", ".2f"),
    ("current_a", ".2f"),
    ("rpm", ".0f"),
    ("temperature_c", ".1f"),
)
"""Status keys of the newest published telemetry sample (``EscTelemetry`` fields) and formats."""

_PORTS: SerialPorts | None = None


def shared_ports() -> SerialPorts:
    """The process's one ``SerialPorts``: every driver in a process reads through it.

    Reads are stamped with the system clock (ROS time without simulated time), as the nodes'
    clocks would.
    """
    global _PORTS
    if _PORTS is None:
        _PORTS = SerialPorts(time.time_ns)
    return _PORTS


@dataclass(frozen=True)
class DriverSettings:
    """The driver's parameters, checked (see ``PARAMETERS`` for meanings and units)."""

    thruster_id: str
    port: str
    baud: int
    protocol: str
    rate_hz: float
    pole_pairs: int
    command_rate_hz: float
    command_timeout_s: float
    max_command_rate_per_s: float
    bridge_timeout_ms: int
    reconnect_period_s: float
    diagnostics_period_s: float

    def __post_init__(self) -> None:
        try:
            check_thruster_id(self.thruster_id)
        except BadInputError as exc:
            raise ValueError(f"parameter thruster_id: {exc}") from None
        if self.protocol not in ("tfdd", "kiss"):
            raise ValueError(f"parameter protocol must be 'tfdd' or 'kiss', got {self.protocol!r}")
        for name in (
            "baud",
            "rate_hz",
            "pole_pairs",
            "command_rate_hz",
            "command_timeout_s",
            "reconnect_period_s",
            "diagnostics_period_s",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"parameter {name} must be positive, got {getattr(self, name)}")
        for name, limit in LIMITS.items():
            value = getattr(self, name)
            if isinstance(limit[0], str):
                continue
            low, high = limit
            if not low <= value <= high:
                raise ValueError(
                    f"parameter {name} must be within {low:g}..{high:g}, got {value:g}"
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


def _sample_values(msg: EscTelemetry | None) -> list[tuple[str, str]]:
    """Status key/values of the newest published telemetry ``msg`` ("-" before the first).

    With ``telemetry_rate_hz`` they are the once-per-period summary a live view reads instead of
    subscribing to the 50 Hz topic (every subscriber of it costs the publisher).
    """
    return [
        (key, "-" if msg is None else format(getattr(msg, key), spec))
        for key, spec in SAMPLE_FORMATS
    ]


class EscDriver(LifecycleNode):
    """The ESC driver of one thruster (see module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("esc_driver", **node_kwargs)
        declare_parameters(self, PARAMETERS, LIMITS)
        self._diag_pub = diagnostics_publisher(self)
        self._local_subscribers: list[Callable[[EscTelemetry], None]] = []
        self._sink: RecordSink | None = None
        self._command_topic = ""
        self._settings: DriverSettings | None = None
        self._link: SerialLink | None = None
        self._active = False
        self._inbox: queue.SimpleQueue[_Received] = queue.SimpleQueue()
        self._drain_pending = False
        # Guards the command state: the reader thread sends, the executor takes commands.
        self._command_lock = threading.Lock()
        # What configure made, with how to destroy it: (destroy, entity).
        self._entities: list[tuple[Callable[[Any], Any], Any]] = []
        self._reset_state()
        if self.get_parameter("autostart").value:
            self._autostart_timer = self.create_timer(0.0, self._autostart)

    def _reset_state(self) -> None:
        # Command state (under _command_lock); its intervals on the monotonic clock.
        settings = self._settings
        self._commands = CommandWatchdog(
            settings.command_timeout_s if settings else 0.5,
            settings.max_command_rate_per_s if settings else 0.0,
        )
        self._tx_seq = 0
        # Telemetry state (executor thread only, but the decoder statistics).
        self._sequence = SequenceWindow()
        self._kiss_seq = 0
        self._last_frame_mono_ns: int | None = None  # monotonic, for staleness
        self._counts = {"frames": 0, "rejected": 0}
        self._reject_reason = ""
        self._bridge_faults = ""
        self._flags_pending = 0
        self._decoder_stats = DecoderStats()
        self._window_start = (dict(self._counts), DecoderStats(), SeqCounts())
        # The newest published telemetry for the status; only a reference per sample, so the
        # 50 Hz path costs what it did.
        self._last_published: EscTelemetry | None = None

    def add_local_subscriber(self, callback: Callable[[EscTelemetry], None]) -> None:
        """Also hand every published telemetry message to ``callback``, in this process.

        Intra-process delivery (as ``NominalModelNode.add_local_subscriber``): a nominal model in
        the same process gets the sample before the DDS write, without DDS and the executor.
        """
        self._local_subscribers.append(callback)

    def record_to(self, sink: RecordSink) -> tuple[str, ...]:
        """Hand every ``esc/telemetry`` message published and every ``esc/command`` taken to
        ``sink`` (the recorder of this process, which then does not subscribe to them over
        DDS); returns both topics, fully qualified."""
        self._sink = sink
        self._command_topic = self.resolve_topic_name("esc/command")
        return (self.resolve_topic_name("esc/telemetry"), self._command_topic)

    # ---- lifecycle -------------------------------------------------------------------------

    def _autostart(self) -> None:
        self.destroy_timer(self._autostart_timer)
        if self.trigger_configure() == TransitionCallbackReturn.SUCCESS:
            self.trigger_activate()

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        p = self.get_parameter
        try:
            settings = DriverSettings(
                thruster_id=str(p("thruster_id").value),
                port=str(p("port").value),
                baud=int(p("baud").value),
                protocol=str(p("protocol").value),
                rate_hz=float(p("rate_hz").value),
                pole_pairs=int(p("pole_pairs").value),
                command_rate_hz=float(p("command_rate_hz").value),
                command_timeout_s=float(p("command_timeout_s").value),
                max_command_rate_per_s=float(p("max_command_rate_per_s").value),
                bridge_timeout_ms=int(p("bridge_timeout_ms").value),
                reconnect_period_s=float(p("reconnect_period_s").value),
                diagnostics_period_s=float(p("diagnostics_period_s").value),
            )
        except ValueError as exc:
            reason = f"cannot configure: {exc}"
            self.get_logger().error(reason)
            thruster_id = str(p("thruster_id").value)
            publish_status(
                self,
                self._diag_pub,
                ERROR,
                status_name("esc", thruster_id),
                reason,
                thruster_id,
                [],
            )
            return TransitionCallbackReturn.FAILURE
        self._settings = settings
        self._reset_state()
        self._pub = self.create_lifecycle_publisher(
            EscTelemetry, "esc/telemetry", qos_profile_sensor_data, event_callbacks=NO_PUB_EVENTS
        )
        # Commands are sent only while active (on_activate starts the ticks of the reader
        # thread). The status timer runs on the steady clock, as the ticks do: a host clock
        # stepped back must not stall commands or status.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        command_sub = self.create_subscription(
            ThrusterCommand,
            "esc/command",
            self._on_command,
            RELIABLE_10,
            event_callbacks=NO_SUB_EVENTS,
        )
        diag_timer = self.create_timer(
            settings.diagnostics_period_s, self._publish_diagnostics, clock=steady
        )
        self._entities = [
            (self.destroy_lifecycle_publisher, self._pub),
            (self.destroy_subscription, command_sub),
            (self.destroy_timer, diag_timer),
        ]
        decoder: FrameDecoder | KissDecoder = (
            KissDecoder(settings.pole_pairs) if settings.protocol == "kiss" else FrameDecoder()
        )
        self._link = shared_ports().open(
            settings.port,
            settings.baud,
            settings.reconnect_period_s,
            lambda data, stamp_ns: self._on_data(decoder, data, stamp_ns),
        )
        self.get_logger().info(
            f"thruster {settings.thruster_id}: {settings.protocol} telemetry on {settings.port} "
            f"at {settings.baud} baud, expecting {settings.rate_hz:g} Hz"
        )
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        with self._command_lock:
            self._commands.restart()
            self._active = True
        if self._link is not None and self._settings is not None:
            shared_ports().start_ticks(
                self._link, 1.0 / self._settings.command_rate_hz, self._send_command
            )
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_commands()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_commands()
        self._release()
        return TransitionCallbackReturn.SUCCESS

    on_error = on_shutdown
    """An error in a transition ends like a shutdown: neutral to the bridge, port closed."""

    def _release(self) -> None:
        """Close the port and destroy what configure made (back to unconfigured)."""
        if self._link is not None:
            shared_ports().close(self._link)
            self._link = None
        for destroy, entity in self._entities:
            destroy(entity)
        self._entities = []
        self._settings = None

    def shutdown(self) -> None:
        """Send neutral to the bridge and close the port (the end of the node's process).

        Not the lifecycle shutdown transition: after Ctrl-C rclpy has already shut the context
        down, and a transition would fail publishing its event before reaching the port.
        """
        self._stop_commands()
        if self._link is not None:
            shared_ports().close(self._link)
            self._link = None

    def _stop_commands(self) -> None:
        """Stop the ticks and send neutral: under the lock, so no tick under way in the reader
        thread can send a command after the neutral frame."""
        if self._link is not None:
            shared_ports().stop_ticks(self._link)
        with self._command_lock:
            self._active = False
            self._commands.stop()
            self._write_command(0.0)

    # ---- serial side (the shared reader thread) --------------------------------------------

    def _on_data(self, decoder: FrameDecoder | KissDecoder, data: bytes, stamp_ns: int) -> None:
        frames = decoder.feed(data)
        self._decoder_stats = decoder.stats()
        if not frames:
            return
        for frame, frame_stamp in zip(
            frames, frame_stamps(stamp_ns, [_mcu_time_us(f) for f in frames]), strict=True
        ):
            self._inbox.put(_Received(frame, frame_stamp))
        # One task per burst: the executor clears the flag before it drains, so a frame that
        # arrives during a drain schedules the next one.
        if not self._drain_pending:
            executor = self.executor
            if executor is not None:
                self._drain_pending = True
                executor.create_task(self._drain)

    # ---- telemetry (executor thread) -------------------------------------------------------

    def _drain(self) -> None:
        self._drain_pending = False
        while True:
            try:
                received = self._inbox.get_nowait()
            except queue.Empty:
                return
            if self._settings is None:
                continue  # frames read just before cleanup
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
        applied = self._commands.applied
        sign = -1.0 if applied < 0 else 1.0
        sample = to_sample(frame)
        sample = TelemetrySample(
            voltage_v=sample.voltage_v,
            current_a=sample.current_a,
            rpm=sign * (sample.rpm or 0.0),
            temperature_c=sample.temperature_c,
            consumption_mah=sample.consumption_mah,
        )
        pwm = command_to_pwm(applied)
        self._publish(self._kiss_seq, sample, applied, pwm, stamp_ns, EscTelemetry.NO_COMMAND_ECHO)

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
        self._counts["frames"] += 1
        self._last_frame_mono_ns = time.monotonic_ns()
        if not self._active:
            return  # inactive: the link is watched, nothing is published
        stats = self._decoder_stats
        window_stats = self._window_start[1]
        if stats.crc_errors > window_stats.crc_errors:
            flags |= EscTelemetry.CRC_ERRORS
        if self._commands.neutral:
            flags |= EscTelemetry.WATCHDOG_NEUTRAL
        if self._bridge_faults:
            flags |= EscTelemetry.BRIDGE_FAULT
        thruster_id = self._settings.thruster_id if self._settings else ""
        msg = EscTelemetry()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        msg.header.frame_id = thruster_id
        msg.thruster_id = thruster_id
        msg.sequence = seq % (1 << 32)
        msg.command = float(command)
        msg.pwm_us = int(pwm_us)
        msg.voltage_v = float(sample.voltage_v or 0.0)
        msg.current_a = float(sample.current_a or 0.0)
        msg.rpm = float(sample.rpm or 0.0)
        msg.temperature_c = float(sample.temperature_c or 0.0)
        msg.status = flags | self._flags_pending
        self._flags_pending = 0
        self._last_published = msg
        for callback in self._local_subscribers:
            callback(msg)
        publish_recorded(self._pub, msg, self._sink)

    # ---- commands (executor thread) --------------------------------------------------------

    def _on_command(self, msg: ThrusterCommand) -> None:
        if self._sink is not None:
            # Taken from DDS as a message: serialised again for the bag.
            self._sink(self._command_topic, ThrusterCommand, serialize_message(msg))
        try:
            with self._command_lock:
                self._commands.command(msg.command)
        except ValueError as exc:
            self.get_logger().warning(f"refused command: {exc}", throttle_duration_sec=1.0)

    # ---- commands (reader thread) ----------------------------------------------------------

    def _send_command(self) -> None:
        with self._command_lock:
            if self._settings is None or not self._active:
                return
            self._write_command(self._commands.step())

    def _write_command(self, command: float) -> None:
        if self._link is None or self._settings is None:
            return
        frame = CommandFrame(command_to_pwm(command), self._settings.bridge_timeout_ms)
        self._link.write(encode_command(frame, self._tx_seq))
        self._tx_seq = (self._tx_seq + 1) % 65536

    # ---- diagnostics -----------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        settings, link = self._settings, self._link
        if settings is None or link is None:
            return
        start_counts, start_stats, start_seq = self._window_start
        stats = self._decoder_stats
        seq = self._sequence.counts()
        last = self._last_frame_mono_ns
        since = None if last is None else (time.monotonic_ns() - last) * 1e-9
        window = LinkWindow(
            period_s=settings.diagnostics_period_s,
            expected_rate_hz=settings.rate_hz,
            port_open=link.is_open,
            port_error=link.error,
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
            watchdog_neutral=self._commands.neutral,
            bridge_faults=self._bridge_faults,
            reconnects=link.reconnects,
        )
        self._window_start = (dict(self._counts), stats, seq)
        health = assess_link(window)
        level, message = health.level, health.message
        if not self._active:
            level = max(level, WARN)
            message = f"inactive (commands not forwarded, telemetry not published); {message}"
        publish_status(
            self,
            self._diag_pub,
            level,
            status_name("esc", settings.thruster_id),
            message,
            settings.thruster_id,
            [("port", settings.port), *health.values, *_sample_values(self._last_published)],
        )


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C (``esc_driver --ros-args -p port:=/dev/ttyUSB0 ...``)."""
    run(EscDriver, args)


if __name__ == "__main__":
    main()
