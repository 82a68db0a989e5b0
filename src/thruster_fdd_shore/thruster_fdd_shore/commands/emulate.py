"""``thruster-fdd emulate``: one simulated thruster's serial bridge on a pseudo-terminal."""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path
from typing import Any

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES
from thruster_fdd.lifetime import stop_with_parent
from thruster_fdd_shore.commands.common import (
    EXIT_OK,
    finite_float,
    non_negative_int,
    positive_float,
)

NAME = "emulate"
HELP = "serve a simulated thruster's serial bridge on a pseudo-terminal"
DESCRIPTION = (
    "Serve one simulated thruster's serial bridge on a pseudo-terminal, in real time, at the "
    "given link path (a symlink to the tty), until Ctrl-C. The ESC driver node opens the link "
    "as it opens a real serial adapter. Only a symlink is ever replaced at the link path. "
    "--bridge firmware runs the bridge's real firmware (firmware/) on an emulated ATmega328P "
    "instead of the Python emulator."
)
BRIDGES = ("python", "firmware")
"""What serves a simulated thruster's bridge: the Python emulator or the firmware co-simulation."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd emulate``."""
    p.add_argument(
        "--link",
        type=Path,
        required=True,
        help="path of the port symlink to create (an existing file there is refused)",
    )
    p.add_argument("--preset", default="t100", help="simulator preset or configuration YAML")
    p.add_argument(
        "--condition",
        default="nominal_15v",
        choices=CLASS_NAMES,
        help="simulated thruster's class (default: %(default)s)",
    )
    p.add_argument(
        "--voltage", type=positive_float, help="supply voltage, V (default: the condition's)"
    )
    p.add_argument("--rate", type=positive_float, default=50.0, help="telemetry rate, Hz (1-1000)")
    p.add_argument(
        "--protocol",
        default="tfdd",
        choices=("tfdd", "kiss"),
        help="telemetry format the bridge sends: tfdd (bridge protocol) or kiss (KISS/BLHeli_32)",
    )
    p.add_argument(
        "--bridge",
        choices=BRIDGES,
        default="python",
        help="the Python emulator, or the bridge firmware on an emulated ATmega328P (tfdd only)",
    )
    p.add_argument(
        "--esc-telemetry",
        choices=("hott", "kiss"),
        default="hott",
        help="with --bridge firmware: the ESC telemetry the firmware reads (its build variant)",
    )
    p.add_argument("--seed", type=non_negative_int, default=0, help="simulator seed")
    p.add_argument(
        "--fault-at", type=finite_float, metavar="S", help="time of the fault after start, s"
    )
    p.add_argument("--fault-condition", choices=CLASS_NAMES, help="condition after --fault-at")


def run(args: argparse.Namespace) -> int:
    """Run one bridge emulator (or the firmware co-simulation) until SIGINT/SIGTERM."""
    from thruster_fdd_shore.core.bridge.emulator import (
        BridgeEmulator,
        EmulatorSettings,
        SetCondition,
    )
    from thruster_fdd_shore.core.sim.config import load_config
    from thruster_fdd_shore.core.sim.physics import ThrusterSimulator

    if (args.fault_at is None) != (args.fault_condition is None):
        raise BadInputError("--fault-at and --fault-condition go together: give both or neither")
    if args.fault_at is not None and args.fault_at < 0:
        raise BadInputError(f"--fault-at must be >= 0 s, got {args.fault_at}")
    settings = EmulatorSettings(rate_hz=args.rate, protocol=args.protocol)
    simulator = ThrusterSimulator(
        load_config(args.preset), args.condition, voltage=args.voltage, seed=args.seed
    )
    if args.bridge == "firmware":
        emulator, fault_type, served_by = _firmware_bridge(args, simulator)
    else:
        emulator = BridgeEmulator(simulator, args.link, settings)
        fault_type, served_by = SetCondition, ""
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    stop_with_parent()
    device = emulator.open()
    if args.fault_at is not None and args.fault_condition is not None:
        fault = fault_type(args.fault_condition)
        timer = threading.Timer(args.fault_at, emulator.inject, (fault,))
        timer.daemon = True
        timer.start()
    print(
        f"emulating {args.condition} ({args.preset}) on {device} via {args.link}{served_by}",
        flush=True,
    )
    emulator.run(stop)
    if args.bridge == "firmware":
        s = emulator.stats
        print(
            f"co-simulation: {s.virtual_s:.1f} s simulated in {s.wall_s:.1f} s ({s.speed:.2f}x "
            f"real time; simulating took {s.busy_s:.1f} s: {s.headroom:.1f}x), {s.slips} slips",
            flush=True,
        )
    return EXIT_OK


def _firmware_bridge(args: argparse.Namespace, simulator: Any) -> tuple[Any, type, str]:
    """``emulate --bridge firmware``: the co-simulated bridge, its fault type and a banner."""
    from thruster_fdd_shore.core.bridge import firmware_cosim as cosim
    from thruster_fdd_shore.core.bridge.firmware_build import ensure_built

    if args.protocol != "tfdd":
        raise BadInputError(
            "the firmware bridge speaks tfdd to the host (--protocol kiss is not it)"
        )
    if not float(args.rate).is_integer():
        raise BadInputError(
            f"the firmware bridge sends whole Hz of telemetry, got --rate {args.rate}"
        )
    settings = cosim.CosimSettings(telemetry_hz=int(args.rate))
    image = ensure_built(args.esc_telemetry)
    bridge = cosim.FirmwareBridge(simulator, args.link, image, settings, seed=args.seed)
    served_by = f": bridge firmware {image.hex_path.name} on an emulated ATmega328P"
    return bridge, cosim.SetCondition, served_by
