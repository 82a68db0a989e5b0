"""The real ESC driver node on the real bridge firmware (co-simulated ATmega328P, HoTT ESC).

The co-simulation runs in a thread of the test process behind a pty; the driver runs as its own
process from its entry module, as ``thruster-fdd up`` starts it; a probe node publishes commands
and collects telemetry and /diagnostics. Timing checks use the co-simulation's virtual time.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import pytest
from probe import Probe, start_node, watch_driver

from thruster_fdd.core.bridge.tfdd import CommandFrame, FrameDecoder, StatusFlag
from thruster_fdd.lifetime import stop_children
from thruster_fdd_shore.core.bridge import firmware_cosim as cosim
from thruster_fdd_shore.core.bridge import hott
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator

pytestmark = pytest.mark.ros

NS = "/thruster/fw"
SERVO_PERIOD_S = 1 / 50
WAKE_S = 0.0011
HOTT_FRAME_S = (44 * 1200 + 10 / hott.BAUD * 1e6) * 1e-6
BRIDGE_TIMEOUT_S = 0.5


@dataclass
class Rig:
    """The co-simulated bridge, the driver process and what the probe collected."""

    bridge: cosim.FirmwareBridge
    driver: subprocess.Popen[bytes]
    probe: Probe
    command_pub: object
    telemetry: list = field(default_factory=list)
    diagnostics: list = field(default_factory=list)

    def spin_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        return self.probe.spin_until(predicate, timeout_s, 0.02)

    def hold(self, value: float, seconds: float) -> None:
        """Publish ``value`` every 50 ms for ``seconds`` of virtual time."""
        from thruster_fdd_msgs.msg import ThrusterCommand

        end = self.bridge.virtual_time + seconds
        while self.bridge.virtual_time < end:
            self.command_pub.publish(ThrusterCommand(command=value))  # type: ignore[attr-defined]
            self.probe.spin(0.05)

    def diag_messages(self, since: int = 0) -> list[tuple[int, str]]:
        return [(s.level[0], s.message) for s in self.diagnostics[since:]]

    def pulses(self, since: float) -> list[cosim.Pulse]:
        return [p for p in list(self.bridge.pulses) if p.t >= since]

    def command_arrivals(self, pwm_us: int) -> list[float]:
        """Virtual times the bridge received command frames for ``pwm_us``, in order."""
        decoder = FrameDecoder()
        times = []
        for chunk in self.bridge.chunks():
            for frame in decoder.feed(chunk.data):
                if frame.message == CommandFrame(pwm_us, 500) and chunk.t_received:
                    times.append(chunk.t_received)
        return times


@pytest.fixture(scope="module")
def rig(
    firmware_images: dict, tmp_path_factory: pytest.TempPathFactory, quiet_t100: object
) -> Iterator[Rig]:
    link = tmp_path_factory.mktemp("pty") / "fw.tty"
    simulator = ThrusterSimulator(quiet_t100, "nominal_15v", seed=7)
    bridge = cosim.FirmwareBridge(simulator, link, firmware_images["hott"], seed=2)
    bridge.open()
    stop = threading.Event()
    thread = threading.Thread(target=bridge.run, args=(stop,), daemon=True)
    thread.start()
    driver = start_node(
        "esc_driver",
        NS,
        {
            "thruster_id": "fw",
            "autostart": True,
            "port": link,
            "rate_hz": 50.0,
            "diagnostics_period_s": 0.5,
            "command_timeout_s": 0.5,
            "max_command_rate_per_s": 0.0,
            "bridge_timeout_ms": int(BRIDGE_TIMEOUT_S * 1000),
        },
    )
    probe = Probe("firmware_probe")
    watch = watch_driver(probe, NS, "fw")
    r = Rig(bridge, driver, probe, watch.command_pub, watch.telemetry, watch.diagnostics)
    try:
        assert r.spin_until(lambda: len(r.telemetry) >= 20, 30.0), "no telemetry from driver"
        assert r.spin_until(lambda: bridge.virtual_time > 2.3, 10.0), "the bridge is arming"
        yield r
    finally:
        stop_children({"esc_driver": driver}, timeout_s=10.0)
        stop.set()
        thread.join(timeout=5)
        probe.close()
        s = bridge.stats
        print(f"co-simulation: {s.virtual_s:.1f} s in {s.wall_s:.1f} s, {s.headroom:.1f}x headroom")


def test_the_driver_publishes_the_firmware_readings_within_the_wire_resolution(rig: Rig) -> None:
    rig.hold(0.5, 3.5)
    n0 = len(rig.telemetry)
    rig.hold(0.5, 1.0)
    published = rig.telemetry[n0:]
    assert 0.8 * 50 <= len(published) <= 1.2 * 50
    served = [s for s in rig.bridge.served() if s.t_sent is not None and not s.fault]
    readings = {
        (s.reading.voltage_v, s.reading.current_a, s.reading.rpm, s.reading.temperature_c)
        for s in served
    }
    for s in served:
        assert s.reading.voltage_v == pytest.approx(s.sample.voltage, abs=0.05 + 1e-9)
        assert s.reading.current_a == pytest.approx(max(0.0, s.sample.current), abs=0.05 + 1e-9)
        assert s.reading.rpm == pytest.approx(abs(s.sample.rpm), abs=5 + 1e-9)
        assert s.reading.temperature_c == pytest.approx(s.sample.temperature, abs=0.5 + 1e-9)
    for msg in published:
        values = (msg.voltage_v, msg.current_a, msg.rpm, msg.temperature_c)
        assert any(values == pytest.approx(r, abs=1e-6) for r in readings), values
        assert msg.pwm_us == 1700
        assert msg.command == pytest.approx(0.5)
        assert msg.status == 0
    assert published[-1].rpm > 1000, "the thruster turns forward, and the rpm says so"
    assert rig.diag_messages()[-1][0] == 0, rig.diag_messages()[-1]


def test_a_command_step_reaches_the_servo_within_one_frame_period(rig: Rig) -> None:
    from thruster_fdd_msgs.msg import EscTelemetry

    rig.hold(0.25, 0.5)
    (first, *_) = rig.command_arrivals(1600)
    pulse = next(p for p in rig.pulses(since=first) if abs(p.width_us - 1600) <= 0.5)
    print(f"first 1600 µs command frame received -> pulse: {pulse.t - first:.4f} s")
    assert pulse.t - first <= SERVO_PERIOD_S + WAKE_S
    echoed: list[EscTelemetry] = [m for m in rig.telemetry if m.pwm_us == 1600]
    assert echoed
    assert echoed[0].command == pytest.approx(0.25)


def test_a_stalled_host_is_caught_by_the_bridge_watchdog(rig: Rig) -> None:
    rig.hold(0.5, 0.5)
    os.kill(rig.driver.pid, signal.SIGSTOP)
    try:
        stalled_at = rig.bridge.virtual_time
        rig.hold(0.5, 1.0)
    finally:
        os.kill(rig.driver.pid, signal.SIGCONT)
    last = max(t for t in rig.command_arrivals(1700) if t < stalled_at + 0.2)
    pulses = rig.pulses(since=last)
    held = [p for p in pulses if p.t < last + BRIDGE_TIMEOUT_S]
    neutral = [p for p in pulses if p.t > last + BRIDGE_TIMEOUT_S + WAKE_S + SERVO_PERIOD_S]
    assert held
    assert all(abs(p.width_us - 1700) <= 0.5 for p in held[1:])
    assert neutral
    assert all(abs(p.width_us - 1500) <= 0.5 for p in neutral)
    # A snapshot: the co-simulation thread appends to the deque meanwhile.
    after = last + BRIDGE_TIMEOUT_S + WAKE_S
    frames = [f.frame.message for f in list(rig.bridge.frames) if f.t > after]
    assert any(f.status & StatusFlag.ESC_TIMEOUT for f in frames)
    rig.hold(0.5, 0.5)
    assert abs(list(rig.bridge.pulses)[-1].width_us - 1700) <= 0.5, "the host is back"


def test_the_driver_watchdog_holds_neutral_when_commands_stop(rig: Rig) -> None:
    from thruster_fdd_msgs.msg import EscTelemetry

    rig.hold(0.5, 0.3)
    n_diag = len(rig.diagnostics)
    # The driver times out 0.5 s of wall-clock time after the last command it received, which a
    # loaded machine delivers late: wait until its telemetry says it holds neutral.
    assert rig.spin_until(
        lambda: bool(rig.telemetry[-1].status & EscTelemetry.WATCHDOG_NEUTRAL), 10.0
    ), "the driver's watchdog never went neutral"
    # Its neutral command frame reaches the bridge within a command period (50 ms).
    since = rig.bridge.virtual_time + 0.1
    rig.spin_until(lambda: rig.bridge.virtual_time > since + 0.5, 10.0)
    late = rig.pulses(since=since)
    assert late
    assert all(abs(p.width_us - 1500) <= 0.5 for p in late)
    assert any("holding neutral" in m for _, m in rig.diag_messages(n_diag))


def test_noise_on_the_host_link_is_flagged_and_not_published(rig: Rig) -> None:
    n0, n_diag = len(rig.telemetry), len(rig.diagnostics)
    start = rig.bridge.virtual_time
    rig.bridge.inject(cosim.HostNoise(300, to_bridge=False))
    rig.bridge.inject(cosim.HostNoise(300, to_bridge=True))
    assert rig.spin_until(lambda: any("noise" in m for _, m in rig.diag_messages(n_diag)), 10.0), (
        rig.diag_messages(n_diag)
    )
    # WARN, or STALE when the noise cost the driver a few frames (the message names both).
    assert any(level in (1, 3) for level, m in rig.diag_messages(n_diag) if "noise" in m)
    served = {s.reading.voltage_v for s in rig.bridge.served() if s.t_sent is not None}
    assert all(m.voltage_v in served for m in rig.telemetry[n0:])
    assert all(abs(p.width_us - 1500) <= 0.5 for p in rig.pulses(since=start))


def test_a_corrupted_esc_frame_is_flagged_and_not_published(rig: Rig) -> None:
    n0, n_diag = len(rig.telemetry), len(rig.diagnostics)
    known = {s.frame_id for s in rig.bridge.served() if s.fault}
    rig.bridge.inject(cosim.CorruptEscFrame())
    assert rig.spin_until(
        lambda: any("ADC_FAULT" in m for _, m in rig.diag_messages(n_diag)), 10.0
    ), rig.diag_messages(n_diag)
    (bad,) = [s for s in rig.bridge.served() if s.fault and s.frame_id not in known]
    bad_voltage = int.from_bytes(bad.data[6:8], "little") / 10
    assert bad_voltage != bad.reading.voltage_v
    published = rig.telemetry[n0:]
    assert published
    assert all(m.voltage_v != pytest.approx(bad_voltage) for m in published)
    assert all(m.voltage_v > 10.0 for m in published), "a flagged (zeroed) sample got through"
    assert any("implausible samples refused" in m for _, m in rig.diag_messages(n_diag))
    assert rig.driver.poll() is None
