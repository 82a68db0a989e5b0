"""ESC driver logic without ROS: command shaping, the command watchdog and serial-link health.

The ``esc_driver`` node calls these and only translates between messages and these types.
Health levels are the values of ``diagnostic_msgs/DiagnosticStatus`` (OK, WARN, ERROR, STALE).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from thruster_fdd.core.bridge.tfdd import NEUTRAL_PWM_US, PWM_PER_UNIT

OK, WARN, ERROR, STALE = 0, 1, 2, 3
"""Health levels, equal to ``diagnostic_msgs.msg.DiagnosticStatus`` OK/WARN/ERROR/STALE."""


def clamp_command(value: float) -> float:
    """Clamp a normalised command to -1..1.

    Raises
    ------
    ValueError
        If ``value`` is NaN or infinite: such a command is refused, not clamped.
    """
    if not math.isfinite(value):
        raise ValueError(f"command {value} is not a finite number")
    return min(1.0, max(-1.0, value))


def slew(previous: float, target: float, dt_s: float, max_rate_per_s: float) -> float:
    """Move from ``previous`` towards ``target`` by at most ``max_rate_per_s * dt_s``.

    ``max_rate_per_s <= 0`` disables the limit (the target is returned).
    """
    if max_rate_per_s <= 0:
        return target
    step = max_rate_per_s * max(0.0, dt_s)
    return previous + min(step, max(-step, target - previous))


class CommandWatchdog:
    """The driver's command state: the target, the watchdog and the slew-limited output.

    Every interval is measured on a monotonic clock, so a host clock stepped back (or forward)
    neither keeps the last command going nor cuts it short.

    Parameters
    ----------
    timeout_s : float
        No command for longer than this -> the target is neutral, s.
    max_rate_per_s : float
        Slew limit of the output, 1/s (``<= 0`` disables it).
    clock_ns : callable, optional
        Monotonic clock, ns; ``time.monotonic_ns`` when None.
    """

    def __init__(
        self,
        timeout_s: float,
        max_rate_per_s: float,
        clock_ns: Callable[[], int] | None = None,
    ) -> None:
        self.timeout_s = timeout_s
        self.max_rate_per_s = max_rate_per_s
        self._clock_ns = clock_ns or time.monotonic_ns
        self.target = 0.0
        self.applied = 0.0
        self.neutral = True
        self._last_command_ns: int | None = None
        self._last_step_ns = self._clock_ns()

    def restart(self) -> None:
        """Forget the last command (neutral until a new one) and restart the slew interval."""
        self._last_command_ns = None
        self._last_step_ns = self._clock_ns()

    def stop(self) -> None:
        """Output and target neutral at once (deactivate, shutdown)."""
        self.applied = self.target = 0.0

    def command(self, value: float) -> None:
        """Take a new command (clamped; ``ValueError`` for a non-finite one, not taken)."""
        self.target = clamp_command(value)
        self._last_command_ns = self._clock_ns()

    def step(self) -> float:
        """The output to send now: the target, or neutral once the watchdog fired, slewed."""
        now = self._clock_ns()
        self.neutral = (
            self._last_command_ns is None
            or not (now - self._last_command_ns) * 1e-9 <= self.timeout_s
        )
        target = 0.0 if self.neutral else self.target
        dt = (now - self._last_step_ns) * 1e-9
        self._last_step_ns = now
        self.applied = slew(self.applied, target, dt, self.max_rate_per_s)
        return self.applied


def command_to_pwm(command: float) -> int:
    """Normalised command (-1..1) to the ESC pulse width in µs (1100..1900)."""
    return round(NEUTRAL_PWM_US + PWM_PER_UNIT * clamp_command(command))


def pwm_to_command(pwm_us: float) -> float:
    """ESC pulse width in µs to the normalised command, ``(pwm_us - 1500) / 400``."""
    return (pwm_us - NEUTRAL_PWM_US) / PWM_PER_UNIT


def frame_stamps(
    received_ns: int, mcu_us: list[int | None], period_ns: int = 1_000_000
) -> list[int]:
    """Host stamps for the frames decoded from one serial read, oldest first.

    The last frame gets the read's host time; earlier ones are placed back by the bridge's own
    clock (microseconds, u32 wrap) when every frame carries it, else ``period_ns`` apart, so
    stamps stay strictly increasing.

    Parameters
    ----------
    received_ns : int
        Host time of the read, ns.
    mcu_us : list of int or None
        Bridge timestamp of each frame, µs, or None when the protocol has none.
    period_ns : int
        Spacing used without bridge timestamps, ns.

    Returns
    -------
    list of int
        One stamp per frame, ns, strictly increasing, the last equal to ``received_ns``.
    """
    n = len(mcu_us)
    if n == 0:
        return []
    last = mcu_us[-1]
    if last is not None and all(t is not None for t in mcu_us):
        back_us = [((last - t) % (1 << 32)) for t in mcu_us]  # type: ignore[operator]
        stamps = [received_ns - 1000 * b for b in back_us]
    else:
        stamps = [received_ns - period_ns * (n - 1 - i) for i in range(n)]
    for i in range(n - 2, -1, -1):
        stamps[i] = min(stamps[i], stamps[i + 1] - 1)
    return stamps


@dataclass(frozen=True)
class LinkWindow:
    """What the driver saw on its serial link during one diagnostics period.

    Counts are increments over the period, except ``reconnects`` (since start).

    Attributes
    ----------
    period_s : float
        Length of the period, s.
    expected_rate_hz : float
        Telemetry rate the bridge is configured for, Hz.
    port_open : bool
        Whether the port is open at the end of the period.
    port_error : str
        Why the port is not open (empty when it is).
    frames : int
        Telemetry frames published.
    crc_errors, truncated, garbage_bytes : int
        Decoder counts: frames with a bad CRC, frames cut short, bytes skipped as noise.
    lost, duplicates : int
        Frames missing from the sequence, and frames received twice (dropped).
    replayed : int
        Frames with a sequence number behind the newest (replays, stale; dropped).
    resets, resyncs : int
        Bridge resets announced by the RESET bit, and sequence restarts without it (the
        sequence window re-anchored, ``core.bridge.sequence``).
    stuck_low_bytes, stuck_high_bytes : int
        Bytes of a line stuck low (runs of 0x00) or high (runs of 0xFF).
    rejected : int
        Frames refused as physically implausible (never published).
    reject_reason : str
        The last reason a frame was refused.
    since_frame_s : float or None
        Time since the last good frame, s; None when none arrived yet.
    watchdog_neutral : bool
        The command watchdog is holding neutral.
    bridge_faults : str
        Fault flags the bridge reported, empty when none.
    reconnects : int
        Times the port was re-opened after being lost.
    """

    period_s: float
    expected_rate_hz: float
    port_open: bool
    port_error: str = ""
    frames: int = 0
    crc_errors: int = 0
    truncated: int = 0
    garbage_bytes: int = 0
    lost: int = 0
    duplicates: int = 0
    replayed: int = 0
    resets: int = 0
    resyncs: int = 0
    stuck_low_bytes: int = 0
    stuck_high_bytes: int = 0
    rejected: int = 0
    reject_reason: str = ""
    since_frame_s: float | None = None
    watchdog_neutral: bool = False
    bridge_faults: str = ""
    reconnects: int = 0


@dataclass(frozen=True)
class LinkHealth:
    """The link's health: a level, one message naming every problem, and key values."""

    level: int
    message: str
    values: tuple[tuple[str, str], ...]


def assess_link(window: LinkWindow, stale_after_periods: float = 5.0) -> LinkHealth:
    """Summarise one diagnostics period of the serial link.

    Parameters
    ----------
    window : LinkWindow
        What was seen in the period.
    stale_after_periods : float
        Telemetry silent for this many frame periods makes the link STALE.

    Returns
    -------
    LinkHealth
        ERROR when the port is closed or the line is stuck with no telemetry; STALE when no
        telemetry arrives (the message names the period's other problems too, so a fault
        flagged just before a silence is still said); WARN for CRC errors, truncated frames,
        noise, lost, duplicated or replayed frames, bridge resets, sequence restarts, stuck
        bytes between frames, refused samples, bridge faults or the watchdog holding neutral;
        OK otherwise.
    """
    rate = window.frames / window.period_s if 0 < window.period_s < math.inf else 0.0
    rate = rate if math.isfinite(rate) else 0.0  # a period of 5e-324 s
    expected = window.expected_rate_hz if 0 < window.expected_rate_hz < math.inf else 0.0
    values = (
        ("telemetry_rate_hz", f"{rate:.1f}"),
        ("expected_rate_hz", f"{expected:.1f}"),
        ("link", "open" if window.port_open else "closed"),
        ("crc_errors", str(window.crc_errors)),
        ("truncated_frames", str(window.truncated)),
        ("garbage_bytes", str(window.garbage_bytes)),
        ("lost_frames", str(window.lost)),
        ("duplicate_frames", str(window.duplicates)),
        ("replayed_frames", str(window.replayed)),
        ("bridge_resets", str(window.resets)),
        ("sequence_restarts", str(window.resyncs)),
        ("stuck_low_bytes", str(window.stuck_low_bytes)),
        ("stuck_high_bytes", str(window.stuck_high_bytes)),
        ("rejected_samples", str(window.rejected)),
        ("reconnects", str(window.reconnects)),
        ("watchdog_neutral", str(window.watchdog_neutral).lower()),
    )
    if not window.port_open:
        return LinkHealth(ERROR, f"serial port not open: {window.port_error}", values)
    stuck = [
        f"line stuck {level}: {count} bytes of {byte}"
        for level, count, byte in (
            ("low", window.stuck_low_bytes, "0x00"),
            ("high", window.stuck_high_bytes, "0xFF"),
        )
        if count
    ]
    if stuck and window.frames == 0:
        return LinkHealth(ERROR, f"{'; '.join(stuck)}, no telemetry (check wiring)", values)
    problems = [
        text
        for count, text in (
            (window.crc_errors, f"{window.crc_errors} CRC errors"),
            (window.truncated, f"{window.truncated} truncated frames"),
            (window.garbage_bytes, f"{window.garbage_bytes} bytes of noise skipped"),
            (window.lost, f"{window.lost} frames lost (sequence gap)"),
            (window.duplicates, f"{window.duplicates} duplicated frames dropped"),
            (window.replayed, f"{window.replayed} replayed or stale frames dropped"),
            (window.resets, f"bridge reset {window.resets} time(s)"),
            (window.resyncs, f"{window.resyncs} sequence restart(s) without RESET"),
            (
                window.rejected,
                f"{window.rejected} implausible samples refused ({window.reject_reason})",
            ),
        )
        if count
    ]
    problems.extend(stuck)
    if window.bridge_faults:
        problems.append(f"bridge reports {window.bridge_faults}")
    if window.watchdog_neutral:
        problems.append("no command within the watchdog timeout: holding neutral")
    seen = f"{'; '.join(problems)} in the last {window.period_s:.1f} s" if problems else ""
    # Without a known rate, silence for a whole diagnostics period is stale.
    stale_s = stale_after_periods / expected if expected else window.period_s
    if window.since_frame_s is None or not window.since_frame_s <= stale_s:
        silent = (
            "no telemetry yet"
            if window.since_frame_s is None
            else (f"no telemetry for {window.since_frame_s:.1f} s")
        )
        message = f"{silent} (expected {expected:g} Hz)" + (f"; {seen}" if seen else "")
        return LinkHealth(STALE, message, values)
    if problems:
        return LinkHealth(WARN, seen, values)
    return LinkHealth(OK, f"telemetry {rate:.1f} Hz", values)
