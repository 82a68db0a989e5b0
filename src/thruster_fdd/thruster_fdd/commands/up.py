"""``thruster-fdd up``: the project's own launcher of the whole node set.

Per thruster it starts the ESC driver node under ``/thruster/<id>`` and, for a simulated thruster
(the default), a microcontroller emulator on a pseudo-terminal (``thruster-fdd emulate``) and a
command player; both model stages of all thrusters run in one container. It prints a live table
until Ctrl-C or ``--duration`` and stops every child cleanly (SIGINT first: the drivers send
neutral to their bridges).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import typing
from dataclasses import dataclass
from pathlib import Path
from types import UnionType
from typing import Any

from thruster_fdd.commands.common import (
    EXIT_FAILED,
    EXIT_OK,
    check_models,
    check_output,
    positive_float,
)
from thruster_fdd.commands.emulate import BRIDGES
from thruster_fdd.core.artifact import CARD_FILE
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES
from thruster_fdd.core.safe_yaml import load_yaml
from thruster_fdd.core.sim.signals import make_signal
from thruster_fdd.lifetime import child_env, node_command, stop_children, stop_with_parent

NAME = "up"
HELP = "start the node set on simulated (default) or real serial thrusters"
DESCRIPTION = (
    "Start the node set. Simulated thrusters (the default) each get a microcontroller emulator "
    "serving the bridge protocol on a pseudo-terminal, an ESC driver node reading it with "
    "pyserial, and a command player; real thrusters (port: in --config) get the driver only. "
    "A recorder writes every topic to MCAP. "
    "Prints a live table per thruster; Ctrl-C stops everything cleanly (neutral commands sent)."
)


MAX_THRUSTERS = 16
"""Most thrusters ``up`` starts (each is 3-4 processes on this machine)."""


PROTOCOLS = ("tfdd", "kiss")
"""Telemetry formats of a bridge (``esc_driver``'s ``protocol``)."""


MAX_SEED = 2**31 - 1
"""Largest seed: it goes to the command player as a ROS integer parameter."""


@dataclass(frozen=True)
class ThrusterPlan:
    """How one thruster of ``up`` is run.

    Attributes
    ----------
    id : str
        Thruster id; its topics live under ``/thruster/<id>``.
    port : str or None
        Serial port of a real bridge; None for a simulated thruster.
    protocol : str
        Telemetry format of the bridge: tfdd or kiss.
    preset : str
        Simulator preset or configuration YAML (simulated thrusters).
    condition : str
        Simulated condition at start.
    seed : int
        Simulator seed (noise and unit-to-unit spread).
    signal : str
        Command signal of the command player (simulated thrusters).
    fault_at_s, fault_condition : float or None, str or None
        Fault injected into the simulated thruster at this time after start.
    bridge : str
        What serves a simulated thruster's bridge: ``python`` (the emulator) or ``firmware``
        (the bridge firmware on an emulated ATmega328P, HoTT ESC telemetry).
    """

    id: str
    port: str | None = None
    protocol: str = "tfdd"
    preset: str = "t100"
    condition: str = "nominal_15v"
    seed: int = 0
    signal: str = "mission"
    fault_at_s: float | None = None
    fault_condition: str | None = None
    bridge: str = "python"

    def __post_init__(self) -> None:
        if not self.id.isidentifier():
            raise BadInputError(f"thruster id {self.id!r} must be a ROS name token like t0")
        if self.protocol not in PROTOCOLS:
            known = ", ".join(PROTOCOLS)
            raise BadInputError(
                f"thruster {self.id}: protocol {self.protocol!r} is not one of {known}"
            )
        if not 0 <= self.seed <= MAX_SEED:
            raise BadInputError(
                f"thruster {self.id}: seed must be within 0..{MAX_SEED}, got {self.seed}"
            )
        for name in ("condition", "fault_condition"):
            value = getattr(self, name)
            if value is not None and value not in CLASS_NAMES:
                raise BadInputError(f"thruster {self.id}: unknown {name} {value!r}")
        if (self.fault_at_s is None) != (self.fault_condition is None):
            raise BadInputError(f"thruster {self.id}: a fault needs both a time and a condition")
        if self.bridge not in BRIDGES:
            raise BadInputError(f"thruster {self.id}: bridge must be one of {BRIDGES}")
        if self.bridge == "firmware" and (self.port is not None or self.protocol != "tfdd"):
            raise BadInputError(
                f"thruster {self.id}: bridge firmware is for simulated thrusters (no port) and "
                "speaks tfdd"
            )
        if self.fault_at_s is not None and not 0.0 <= self.fault_at_s < math.inf:
            raise BadInputError(
                f"thruster {self.id}: fault time must be a finite number >= 0 s, got "
                f"{self.fault_at_s}"
            )


@dataclass(frozen=True)
class ModelStage:
    """A node of the per-thruster pipeline that runs an exported model from ``folder``."""

    node: str
    folder: str


MODEL_STAGES = (ModelStage("nominal_model", "nominal"), ModelStage("classifier", "classifier"))


PLAYER_RATE_HZ = 20.0
"""The command player's publishing rate (its ``rate_hz`` default), to check signal specs."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd up``."""
    p.add_argument("--config", type=Path, help="YAML with rate_hz and a thrusters: list")
    p.add_argument("--thrusters", type=int, default=1, help="number of simulated thrusters (1-16)")
    p.add_argument("--preset", default="t100", help="simulator preset or configuration YAML")
    p.add_argument("--rate", type=float, default=50.0, help="telemetry rate, Hz (10-100)")
    p.add_argument("--signal", default="mission", help="command signal of simulated thrusters")
    p.add_argument(
        "--bridge",
        choices=BRIDGES,
        default="python",
        help="what serves simulated thrusters' bridges (a config entry's bridge: key wins): the "
        "Python emulator or the bridge firmware on an emulated ATmega328P",
    )
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="ID:CONDITION@S",
        help="inject a condition into a simulated thruster at S seconds, e.g. t0:broken_blade_1@20",
    )
    p.add_argument(
        "--duration", type=positive_float, help="stop after this many seconds (default: Ctrl-C)"
    )
    p.add_argument(
        "--print-period", type=positive_float, default=2.0, help="table refresh period, s"
    )
    p.add_argument(
        "--record-dir",
        type=Path,
        default=Path("recordings"),
        help="the recorder writes every topic to MCAP files here",
    )
    p.add_argument("--no-record", action="store_true", help="do not start the recorder")
    p.add_argument(
        "--models",
        type=Path,
        help="folder with nominal/ and classifier/ exported models (default: the workspace's "
        "models/); a node whose model is absent is not started",
    )


def _typed(value: Any, hint: Any, where: str) -> Any:
    """``value`` from YAML as a ``ThrusterPlan`` field of type ``hint`` (str, int, float or
    one of them or None); BadInputError naming ``where`` when it is not."""
    options = (
        typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, UnionType) else (hint,)
    )
    if value is None and type(None) in options:
        return None
    if str in options and isinstance(value, str):
        return value
    if int in options and isinstance(value, int) and not isinstance(value, bool):
        return value
    if float in options and isinstance(value, int | float) and not isinstance(value, bool):
        return float(value) if abs(value) < 1e300 else math.inf  # an int too large for a float
    names = {str: "a string", int: "an integer", float: "a number", type(None): "null"}
    expected = " or ".join(names[t] for t in options)
    raise BadInputError(f"{where} must be {expected}, got {value!r}")


def _plans_from_config(
    path: Path, default_rate: float, default_bridge: str
) -> tuple[float, list[ThrusterPlan]]:
    """The telemetry rate and thrusters of an ``up --config`` file (``config/up.yaml``); a
    simulated thruster's bridge is ``default_bridge`` unless its entry says."""
    spec = load_yaml(path.read_text(encoding="utf-8", errors="replace"), str(path))
    if spec is None:
        spec = {}
    if not isinstance(spec, dict):
        raise BadInputError(f"{path}: expected a mapping with rate_hz and thrusters")
    unknown = sorted(set(map(str, spec)) - {"rate_hz", "thrusters"})
    if unknown:
        raise BadInputError(f"{path}: unknown key(s) {', '.join(unknown)}")
    rate = _typed(spec.get("rate_hz", default_rate), float, f"{path}: rate_hz")
    entries = spec.get("thrusters")
    if not isinstance(entries, list) or not entries:
        raise BadInputError(f"{path}: needs a non-empty 'thrusters:' list")
    hints = typing.get_type_hints(ThrusterPlan)
    plans = []
    for i, entry in enumerate(entries):
        where = f"{path}: thrusters[{i}]"
        if not isinstance(entry, dict):
            raise BadInputError(f"{where} must be a mapping like {{id: t0}}, got {entry!r}")
        unknown = sorted(set(map(str, entry)) - set(hints))
        if unknown:
            raise BadInputError(f"{where}: unknown key(s) {', '.join(unknown)}")
        if "id" not in entry:
            raise BadInputError(f"{where}: needs an id")
        values = {k: _typed(v, hints[k], f"{where}.{k}") for k, v in entry.items()}
        defaults = {} if "port" in values else {"bridge": default_bridge}
        plans.append(ThrusterPlan(**(defaults | values)))
    return rate, plans


def _fault(text: str, ids: set[str]) -> tuple[str, str, float]:
    """(id, condition, time s) of a ``--fault ID:CONDITION@S``."""
    tid, _, rest = text.partition(":")
    condition, _, at = rest.partition("@")
    try:
        at_s = float(at)
    except ValueError:
        at_s = math.nan
    if tid not in ids or not condition or not 0.0 <= at_s < math.inf:
        raise BadInputError(
            f"--fault {text!r}: expected ID:CONDITION@SECONDS with a known id and a finite "
            f"time >= 0 (ids: {', '.join(sorted(ids))})"
        )
    return tid, condition, at_s


def plan_from_args(args: argparse.Namespace) -> tuple[float, tuple[ThrusterPlan, ...]]:
    """The telemetry rate and the thrusters to run, from ``up``'s options or its --config.

    Raises
    ------
    BadInputError
        Naming the option or the config file's entry that is wrong: a config that is not plain
        YAML (``core.safe_yaml``), a value of the wrong type, an unknown key, condition,
        protocol or signal, a rate outside 1..1000 Hz, more than ``MAX_THRUSTERS`` thrusters,
        repeated ids, a malformed ``--fault``.
    """
    if args.config is not None:
        rate, plans = _plans_from_config(Path(args.config), args.rate, args.bridge)
    else:
        if not 1 <= args.thrusters <= MAX_THRUSTERS:
            raise BadInputError(
                f"--thrusters must be within 1..{MAX_THRUSTERS}, got {args.thrusters}"
            )
        rate = args.rate
        plans = [
            ThrusterPlan(
                id=f"t{i}", preset=args.preset, seed=i, signal=args.signal, bridge=args.bridge
            )
            for i in range(args.thrusters)
        ]
    if not 1.0 <= rate <= 1000.0:
        raise BadInputError(f"telemetry rate must be within 1..1000 Hz, got {rate}")
    firmware = any(p.bridge == "firmware" for p in plans)
    if firmware and not (rate.is_integer() and 10 <= rate <= 100):
        raise BadInputError(
            f"the firmware bridge sends 10..100 whole Hz of telemetry, got {rate:g}"
        )
    if len(plans) > MAX_THRUSTERS:
        raise BadInputError(f"at most {MAX_THRUSTERS} thrusters, got {len(plans)}")
    by_id = {p.id: p for p in plans}
    if len(by_id) != len(plans):
        raise BadInputError("thruster ids must be unique")
    for text in args.fault:
        tid, condition, at_s = _fault(text, set(by_id))
        by_id[tid] = ThrusterPlan(
            **{**by_id[tid].__dict__, "fault_at_s": at_s, "fault_condition": condition}
        )
    for plan in by_id.values():
        if plan.port is None:
            try:
                make_signal(plan.signal, 1.0, PLAYER_RATE_HZ)
            except BadInputError as exc:
                raise BadInputError(f"thruster {plan.id}: signal: {exc}") from None
    return rate, tuple(by_id[p.id] for p in plans)


def _check_inputs(args: argparse.Namespace, plans: tuple[ThrusterPlan, ...], models: Path) -> None:
    """What the children would fail on, said before they start (exit 2): simulator presets,
    the recording folder, exported models."""
    from thruster_fdd.core.sim.config import load_config

    for preset in sorted({p.preset for p in plans if p.port is None}):
        load_config(preset)
    if not args.no_record:
        check_output(args.record_dir, "--record-dir", folder=True)
    if (models / "nominal" / CARD_FILE).is_file():
        check_models(models)


def _commands(plan: ThrusterPlan, rate: float, run_dir: Path) -> dict[str, list[str]]:
    ns = f"/thruster/{plan.id}"
    port = plan.port or str(run_dir / f"{plan.id}.tty")
    out: dict[str, list[str]] = {}
    if plan.port is None:
        emulate = [sys.executable, "-m", "thruster_fdd.cli", "emulate", "--link", port]
        emulate += ["--preset", plan.preset, "--condition", plan.condition]
        emulate += ["--rate", str(rate), "--seed", str(plan.seed), "--protocol", plan.protocol]
        emulate += ["--bridge", plan.bridge]
        if plan.fault_at_s is not None and plan.fault_condition is not None:
            emulate += ["--fault-at", str(plan.fault_at_s)]
            emulate += ["--fault-condition", plan.fault_condition]
        out[f"{plan.id}-emulator"] = emulate
        out[f"{plan.id}-commands"] = node_command(
            "command_player", ns, {"signal": plan.signal, "seed": plan.seed}
        )
    out[f"{plan.id}-esc_driver"] = node_command(
        "esc_driver",
        ns,
        {"thruster_id": plan.id, "port": port, "protocol": plan.protocol, "rate_hz": rate},
    )
    return out


def _stage_commands(ids: list[str], models: Path) -> dict[str, list[str]]:
    """One container hosting every thruster's node of each model stage whose model is exported
    (``nodes/container.py``: torch loaded once; residuals stay in the process)."""
    stages = [st for st in MODEL_STAGES if (models / st.folder / CARD_FILE).is_file()]
    if not stages:
        return {}
    cmd = [sys.executable, "-m", "thruster_fdd.nodes.container", *(st.node for st in stages)]
    cmd += ["--thrusters", *ids]
    for st in stages:
        cmd += ["-p", f"{st.node}:model_dir={models / st.folder}"]
    return {"models": cmd}


def run(args: argparse.Namespace) -> int:
    """Start the node set, print the live table, stop everything on Ctrl-C or --duration."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from thruster_fdd.core.artifact import default_models_dir
    from thruster_fdd.nodes.monitor import Monitor

    rate, plans = plan_from_args(args)
    if any(p.bridge == "firmware" for p in plans):
        from thruster_fdd.core.bridge.firmware_build import ensure_built

        # Once here rather than in every emulator at once.
        ensure_built("hott")
    models = (args.models or default_models_dir()).resolve()
    _check_inputs(args, plans, models)
    run_dir = Path(tempfile.mkdtemp(prefix="thruster_fdd-up-"))
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    stop_with_parent()

    children: dict[str, subprocess.Popen[bytes]] = {}
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    monitor = Monitor([p.id for p in plans])
    executor = SingleThreadedExecutor()
    executor.add_node(monitor)
    try:
        # The recorder starts first, so it is listening when the first telemetry comes.
        commands: dict[str, list[str]] = {}
        if not args.no_record:
            prefix = f"up_{time.strftime('%Y%m%d_%H%M%S')}"
            model_ids = ",".join(
                f"{stage.folder}={json.loads(card.read_text())['model_id']}"
                for stage in MODEL_STAGES
                if (card := models / stage.folder / CARD_FILE).is_file()
            )
            recorder = node_command(
                "recorder",
                "/",
                {
                    "output_dir": args.record_dir.resolve(),
                    "prefix": prefix,
                    "model_ids": f"'{model_ids}'",
                },
            )
            commands["recorder"] = recorder
        commands |= _stage_commands([p.id for p in plans], models)
        # One reference thruster type for the vehicle's effectiveness estimates: the first's.
        ids = ",".join(p.id for p in plans)
        commands["health"] = node_command(
            "health", "/", {"thruster_ids": f"[{ids}]", "preset": plans[0].preset}
        )
        for plan in plans:
            commands |= _commands(plan, rate, run_dir)
        for name, cmd in commands.items():
            log = (run_dir / f"{name}.log").open("wb")
            # Own process group: a Ctrl-C reaches children only through stop_children,
            # so they stop in order after the table's last print.
            children[name] = subprocess.Popen(
                cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, env=child_env()
            )
        kinds = ", ".join(
            f"{p.id}: {'serial ' + p.port if p.port else 'simulated ' + p.preset}" for p in plans
        )
        print(f"thruster-fdd up: {len(plans)} thruster(s) at {rate:g} Hz ({kinds})")
        print(f"ports and logs: {run_dir}   (ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', 0)})")
        stages = [
            f"{st.node} ({models / st.folder})"
            for st in MODEL_STAGES
            if (models / st.folder / CARD_FILE).is_file()
        ]
        print(f"models: {', '.join(stages) if stages else f'none in {models}'}")
        if not args.no_record:
            print(f"recording every topic to the bag {args.record_dir.resolve() / prefix}")
        print("Ctrl-C stops" if args.duration is None else f"running for {args.duration:g} s")
        start = time.monotonic()
        next_print = start + args.print_period
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            if args.duration is not None and now - start >= args.duration:
                break
            if now >= next_print:
                next_print += args.print_period
                print(f"\n[t = {now - start:5.1f} s]\n{monitor.table()}", flush=True)
            dead = [n for n, proc in children.items() if proc.poll() is not None]
            if dead:
                print(f"thruster-fdd up: {', '.join(dead)} exited; see {run_dir}", file=sys.stderr)
                return EXIT_FAILED
        print(f"\nfinal:\n{monitor.table()}")
        return EXIT_OK
    finally:
        stop_children(children, timeout_s=5.0)
        executor.shutdown()
        monitor.destroy_node()
        rclpy.try_shutdown()
