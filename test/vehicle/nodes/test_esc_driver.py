"""Emulator + ESC driver node on a real pty and a real rclpy graph, with injected link faults,
and the driver's lifecycle walked through its services.

The emulator (a simulated t100 behind the bridge protocol) runs in a thread of the test process;
the driver runs as its own process from its entry module and is configured and activated
through its lifecycle services, as ``thruster-fdd up`` does; a probe node here publishes
commands and collects telemetry and /diagnostics.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from probe import Probe, non_finite_fields, start_node, watch_driver

from thruster_fdd.lifetime import stop_children
from thruster_fdd_shore.core.bridge.emulator import (
    BridgeEmulator,
    BridgeReset,
    CorruptCrc,
    Disconnect,
    DuplicateFrame,
    EmulatorSettings,
    Fault,
    Garbage,
    OutOfRange,
    ReplayFrames,
    Silence,
    SkipSequence,
    StuckLine,
    Truncate,
)
from thruster_fdd_shore.core.sim.config import load_config
from thruster_fdd_shore.core.sim.physics import ThrusterSimulator
from thruster_fdd_shore.nodes.lifecycle_client import change_states, get_state

pytestmark = pytest.mark.ros

RATE_HZ = 50.0
NS = "/thruster/it"
DRIVER = f"{NS}/esc_driver"


@dataclass
class Rig:
    """The emulator, the driver process and the probe's collected messages."""

    emulator: BridgeEmulator
    driver: subprocess.Popen[bytes]
    probe: Probe
    command_pub: object
    telemetry: list = field(default_factory=list)
    diagnostics: list = field(default_factory=list)

    def spin_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        return self.probe.spin_until(predicate, timeout_s, 0.02)

    def spin_for(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def command(self, value: float) -> None:
        from thruster_fdd_msgs.msg import ThrusterCommand

        self.command_pub.publish(ThrusterCommand(command=value))  # type: ignore[attr-defined]

    def diag_messages(self, since: int = 0) -> list[tuple[int, str]]:
        return [(s.level[0], s.message) for s in self.diagnostics[since:]]


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory, quiet_t100: object) -> Iterator[Rig]:
    link_path = tmp_path_factory.mktemp("pty") / "it.tty"
    simulator = ThrusterSimulator(quiet_t100, "nominal_15v", seed=3)
    emulator = BridgeEmulator(simulator, link_path, EmulatorSettings(rate_hz=RATE_HZ))
    emulator.open()
    stop_event = threading.Event()
    thread = threading.Thread(target=emulator.run, args=(stop_event,), daemon=True)
    thread.start()

    driver = start_node(
        "esc_driver",
        NS,
        {
            "thruster_id": "it",
            "port": link_path,
            "rate_hz": RATE_HZ,
            "diagnostics_period_s": 0.5,
            "command_timeout_s": 0.5,
            "max_command_rate_per_s": 0.0,
        },
    )
    probe = Probe("probe")
    watch = watch_driver(probe, NS, "it")
    r = Rig(emulator, driver, probe, watch.command_pub, watch.telemetry, watch.diagnostics)
    try:
        for transition in ("configure", "activate"):
            assert change_states(probe.node, probe.executor, [DRIVER], transition, 30.0) == {}
        assert r.spin_until(lambda: len(r.telemetry) >= 20, 20.0), "no telemetry from driver"
        yield r
    finally:
        stop_children({"esc_driver": driver}, timeout_s=10.0)
        stop_event.set()
        thread.join(timeout=5)
        probe.close()


def test_telemetry_flows_at_the_bridge_rate(rig: Rig) -> None:
    n0 = len(rig.telemetry)
    rig.spin_for(2.0)
    rate = (len(rig.telemetry) - n0) / 2.0
    assert 0.8 * RATE_HZ <= rate <= 1.2 * RATE_HZ
    last = rig.telemetry[-1]
    assert last.thruster_id == "it"
    assert 14.0 < last.voltage_v < 16.0
    seqs = [m.sequence for m in rig.telemetry[n0:]]
    assert seqs == sorted(seqs)


def _sample_summary(m: Any) -> tuple[str, ...]:
    """A telemetry message as the driver's status renders it (docs/contracts.md)."""
    return (
        f"{m.command:.2f}",
        str(m.pwm_us),
        f"{m.voltage_v:.2f}",
        f"{m.current_a:.2f}",
        f"{m.rpm:.0f}",
        f"{m.temperature_c:.1f}",
    )


def test_status_summarises_the_rate_and_the_newest_published_sample(rig: Rig) -> None:
    """What the live table reads instead of the 50 Hz topic: a period's status carries the
    published rate and the sample published last (one the probe received just before)."""

    def hold(until: Callable[[], bool], timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while not until():
            assert time.monotonic() < deadline, "no status from the driver"
            rig.command(0.3)
            rig.spin_for(0.05)

    # A whole period at 0.3 first, so that the sample is not an idle one.
    end = time.monotonic() + 1.5
    hold(lambda: time.monotonic() >= end, 2.0)
    n0 = len(rig.diagnostics)
    hold(lambda: len(rig.diagnostics) > n0, 10.0)
    rig.spin_for(0.1)  # samples published before the status, on the other topic
    values = {kv.key: kv.value for kv in rig.diagnostics[-1].values}
    assert 0.8 * RATE_HZ <= float(values["telemetry_rate_hz"]) <= 1.2 * RATE_HZ, values
    keys = ("command", "pwm_us", "voltage_v", "current_a", "rpm", "temperature_c")
    summary = tuple(values[k] for k in keys)
    assert summary in [_sample_summary(m) for m in rig.telemetry[-25:]], values
    assert values["command"] == "0.30"
    assert float(values["rpm"]) > 500.0


def test_commands_are_forwarded_and_clamped(rig: Rig) -> None:
    def hold(value: float, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rig.command(value)
            rig.spin_for(0.05)

    hold(0.5, 1.0)
    assert rig.emulator.pwm_us == 1700
    assert rig.telemetry[-1].command == pytest.approx(0.5)
    hold(3.0, 0.5)
    assert rig.emulator.pwm_us == 1900
    hold(float("nan"), 0.3)
    assert rig.emulator.pwm_us == 1900, "a NaN command must be refused, not applied"
    hold(0.5, 3.0)
    assert abs(rig.telemetry[-1].rpm) > 1000, "the simulated thruster should spin"


def test_watchdog_falls_back_to_neutral(rig: Rig) -> None:
    from thruster_fdd_msgs.msg import EscTelemetry

    for _ in range(10):
        rig.command(0.4)
        rig.spin_for(0.05)
    assert rig.emulator.pwm_us == 1660
    n0 = len(rig.diagnostics)
    assert rig.spin_until(lambda: rig.emulator.pwm_us == 1500, 10.0)
    assert rig.spin_until(lambda: any("neutral" in m for _, m in rig.diag_messages(n0)), 10.0), (
        rig.diag_messages(n0)
    )
    # The frame received last may have been published just before the watchdog fired: wait
    # for one that carries the flag, as the firmware-bridge test does.
    assert rig.spin_until(
        lambda: bool(rig.telemetry[-1].status & EscTelemetry.WATCHDOG_NEUTRAL), 10.0
    )


def _inject_and_watch(rig: Rig, fault: Fault, words: str) -> list[tuple[int, str]]:
    n0 = len(rig.diagnostics)
    rig.emulator.inject(fault)
    assert rig.spin_until(lambda: any(words in m for _, m in rig.diag_messages(n0)), 10.0), (
        f"no /diagnostics message with {words!r} after {fault}: {rig.diag_messages(n0)}"
    )
    return rig.diag_messages(n0)


@pytest.mark.parametrize(
    ("fault", "words"),
    [
        (Garbage(200), "noise"),
        (CorruptCrc(5), "CRC errors"),
        (Truncate(3), "truncated"),
        (DuplicateFrame(4), "duplicated"),
        (SkipSequence(7), "7 frames lost"),
        (OutOfRange(3), "implausible"),
        (ReplayFrames(back=8, count=5), "5 replayed"),
        (BridgeReset(), "bridge reset 1 time"),
    ],
)
def test_link_faults_are_reported_and_never_published(rig: Rig, fault: Fault, words: str) -> None:
    n0 = len(rig.telemetry)
    messages = _inject_and_watch(rig, fault, words)
    assert any(level == 1 for level, m in messages if words in m)
    rig.spin_for(0.3)
    published = rig.telemetry[n0:]
    volts = [m.voltage_v for m in published]
    assert max(volts) - min(volts) < 0.4, "a corrupted or implausible voltage got through"
    seqs = [m.sequence for m in published]
    assert len(seqs) == len(set(seqs)), "a duplicated frame was published"
    assert len(published) > 0.5 * RATE_HZ * 0.5


def test_sequence_gap_flags_the_next_sample(rig: Rig) -> None:
    from thruster_fdd_msgs.msg import EscTelemetry

    n0 = len(rig.telemetry)
    rig.emulator.inject(SkipSequence(3))
    rig.spin_for(0.5)
    assert any(m.status & EscTelemetry.SEQUENCE_GAP for m in rig.telemetry[n0:])


def test_stuck_line_is_a_link_error_never_telemetry(rig: Rig) -> None:
    n_diag = len(rig.diagnostics)
    rig.emulator.inject(StuckLine(0x00, 2.0))
    assert rig.spin_until(
        lambda: any(level == 2 and "stuck low" in m for level, m in rig.diag_messages(n_diag)),
        10.0,
    ), rig.diag_messages(n_diag)
    n0 = len(rig.telemetry)
    rig.spin_for(0.5)
    assert all(m.voltage_v > 10.0 for m in rig.telemetry[n0:]), "a stuck line was published"
    assert rig.spin_until(lambda: len(rig.telemetry) > n0 + 10, 10.0), "no recovery"


def test_silent_port_goes_stale_then_recovers(rig: Rig) -> None:
    messages = _inject_and_watch(rig, Silence(2.0), "no telemetry")
    assert any(level == 3 for level, _ in messages)
    n0 = len(rig.telemetry)
    assert rig.spin_until(lambda: len(rig.telemetry) > n0 + 10, 10.0)


def test_port_that_disappears_is_reopened_within_2_s(rig: Rig) -> None:
    n_diag = len(rig.diagnostics)
    rig.emulator.inject(Disconnect(1.5))
    assert rig.spin_until(
        lambda: any(level == 2 and "not open" in m for level, m in rig.diag_messages(n_diag)), 10.0
    ), rig.diag_messages(n_diag)
    assert rig.spin_until(lambda: rig.emulator.link.exists(), 5.0)
    back = time.monotonic()
    n0 = len(rig.telemetry)
    assert rig.spin_until(lambda: len(rig.telemetry) > n0, 2.0), "not reconnected within 2 s"
    print(f"reconnected {time.monotonic() - back:.2f} s after the port returned")
    assert rig.driver.poll() is None, "the driver must survive a vanishing port"


def test_driver_survived_everything(rig: Rig) -> None:
    assert rig.driver.poll() is None
    n0 = len(rig.telemetry)
    rig.spin_for(1.0)
    assert len(rig.telemetry) - n0 > 0.8 * RATE_HZ


def test_every_published_telemetry_field_is_finite(rig: Rig) -> None:
    """After every link fault above, no published telemetry field is non-finite."""
    assert len(rig.telemetry) > 20
    assert [m.sequence for m in rig.telemetry if non_finite_fields(m)] == []


def test_kiss_telemetry_is_decoded(tmp_path: Path) -> None:
    """The driver's second protocol: KISS/BLHeli_32 telemetry from the same emulator."""
    from rclpy.qos import qos_profile_sensor_data
    from thruster_fdd_msgs.msg import EscTelemetry

    link_path = tmp_path / "kiss.tty"
    simulator = ThrusterSimulator(load_config("t100"), "nominal_15v", seed=4)
    emulator = BridgeEmulator(
        simulator, link_path, EmulatorSettings(rate_hz=RATE_HZ, protocol="kiss")
    )
    emulator.open()
    stop_event = threading.Event()
    thread = threading.Thread(target=emulator.run, args=(stop_event,), daemon=True)
    thread.start()
    params = {"port": link_path, "protocol": "kiss", "thruster_id": "kiss", "autostart": True}
    driver = start_node("esc_driver", "/thruster/kiss", params)
    received: list[EscTelemetry] = []
    with Probe("kiss_probe") as probe:
        probe.node.create_subscription(
            EscTelemetry, "/thruster/kiss/esc/telemetry", received.append, qos_profile_sensor_data
        )
        try:
            probe.spin_until(lambda: len(received) >= 20, 20.0, 0.05)
        finally:
            stop_children({"esc_driver": driver}, timeout_s=10.0)
            stop_event.set()
            thread.join(timeout=5)
    assert len(received) >= 20
    assert all(m.status & EscTelemetry.NO_COMMAND_ECHO for m in received)
    assert 14.0 < received[-1].voltage_v < 16.0


def _open_devices(pid: int) -> set[str]:
    """What the file descriptors of process ``pid`` point at."""
    out = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):
            out.add(os.readlink(fd))
    return out


def test_lifecycle_transitions_walked_on_a_pty(tmp_path: Path, quiet_t100: object) -> None:
    """unconfigured: port closed, nothing published; a bad parameter fails configure;
    configure: port open, link reported, nothing published; activate: telemetry flows and
    commands are forwarded; deactivate: neutral at once (before the bridge's own watchdog),
    commands ignored, telemetry stops; cleanup: port closed; configure + activate again;
    shutdown: finalized, neutral."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from thruster_fdd_msgs.msg import EscTelemetry, ThrusterCommand

    node_name = "/thruster/lc/esc_driver"
    simulator = ThrusterSimulator(quiet_t100, "nominal_15v", seed=5)
    emulator = BridgeEmulator(simulator, tmp_path / "lc.tty", EmulatorSettings(rate_hz=RATE_HZ))
    device = emulator.open()
    stop_event = threading.Event()
    thread = threading.Thread(target=emulator.run, args=(stop_event,), daemon=True)
    thread.start()
    params = {
        "port": tmp_path / "lc.tty",
        "thruster_id": "lc",
        "diagnostics_period_s": 0.5,
        "command_timeout_s": 5.0,
        "max_command_rate_per_s": 0.0,
        # The bridge's own watchdog far away: only the driver's neutral frame resets it fast.
        "bridge_timeout_ms": 10000,
    }
    driver = start_node("esc_driver", "/thruster/lc", params)
    telemetry: list[EscTelemetry] = []
    statuses: list[tuple[int, str]] = []
    with Probe("lifecycle_probe") as probe:
        reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        probe.node.create_subscription(
            EscTelemetry, "/thruster/lc/esc/telemetry", telemetry.append, qos_profile_sensor_data
        )
        probe.node.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda m: statuses.extend(
                (s.level[0], s.message) for s in m.status if s.name == "thruster_fdd: esc lc"
            ),
            reliable,
        )
        commands = probe.node.create_publisher(
            ThrusterCommand, "/thruster/lc/esc/command", reliable
        )

        def change(transition: str) -> dict[str, str]:
            return change_states(probe.node, probe.executor, [node_name], transition, 30.0)

        def state() -> str | None:
            return get_state(probe.node, probe.executor, node_name, 30.0)

        def command_for(value: float, seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                commands.publish(ThrusterCommand(command=value))
                probe.spin(0.05)

        def port_open() -> bool:
            return device in _open_devices(driver.pid)

        try:
            assert state() == "unconfigured"
            probe.spin(1.0)
            assert telemetry == []
            assert not port_open()

            parameters = AsyncParameterClient(probe.node, node_name)
            assert parameters.wait_for_services(timeout_sec=30.0)
            for protocol, expected in (("bogus", False), ("tfdd", True)):
                request = [Parameter("protocol", value=protocol)]
                assert probe.ask(lambda r=request: parameters.set_parameters(r), 10.0) is not None
                assert (change("configure") == {}) is expected
            assert state() == "inactive"
            assert probe.spin_until(port_open, 2.0), "configure did not open the port"
            assert probe.spin_until(lambda: any("inactive" in m for _, m in statuses), 10.0)
            assert all(level >= 1 for level, m in statuses if "inactive" in m)
            assert telemetry == [], "an inactive driver published telemetry"

            assert change("activate") == {}
            assert probe.spin_until(lambda: len(telemetry) >= 10, 5.0)
            command_for(0.5, 1.0)
            assert emulator.pwm_us == 1700

            assert change("deactivate") == {}
            assert probe.spin_until(lambda: emulator.pwm_us == 1500, 0.5), "no neutral sent"
            n_before = len(telemetry)
            command_for(0.5, 1.0)
            assert emulator.pwm_us == 1500, "an inactive driver forwarded a command"
            assert len(telemetry) - n_before <= 2, "an inactive driver published telemetry"

            assert change("cleanup") == {}
            assert probe.spin_until(lambda: not port_open(), 2.0), "cleanup left the port open"
            assert state() == "unconfigured"

            for transition in ("configure", "activate"):
                assert change(transition) == {}
            n_before = len(telemetry)
            assert probe.spin_until(lambda: len(telemetry) >= n_before + 10, 5.0)
            command_for(-0.25, 0.5)
            assert emulator.pwm_us == 1400
            assert change("shutdown") == {}
            assert state() == "finalized"
            assert probe.spin_until(lambda: emulator.pwm_us == 1500, 0.5)
            assert probe.spin_until(lambda: not port_open(), 2.0)
        finally:
            stop_children({"esc_driver": driver}, timeout_s=10.0)
            stop_event.set()
            thread.join(timeout=5)


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("bridge_timeout_ms", 0),
        ("bridge_timeout_ms", 70000),
        ("rate_hz", 100000.0),
        ("command_rate_hz", 1e-300),
        ("baud", 10**23),
    ],
)
def test_settings_out_of_the_declared_range_are_refused_at_configure(
    name: str, value: float
) -> None:
    from dataclasses import replace

    from thruster_fdd.nodes.esc_driver import DriverSettings

    good = DriverSettings(
        thruster_id="t0",
        port="/dev/null",
        baud=115200,
        protocol="tfdd",
        rate_hz=50.0,
        pole_pairs=7,
        command_rate_hz=20.0,
        command_timeout_s=0.5,
        max_command_rate_per_s=4.0,
        bridge_timeout_ms=500,
        reconnect_period_s=0.25,
        diagnostics_period_s=1.0,
    )
    with pytest.raises(ValueError, match=rf"parameter {name} must be within"):
        replace(good, **{name: value})
    with pytest.raises(ValueError, match="thruster_id"):
        replace(good, thruster_id="tä")
