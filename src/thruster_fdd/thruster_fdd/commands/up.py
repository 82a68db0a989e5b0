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
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from thruster_fdd.commands.common import EXIT_FAILED, EXIT_OK
from thruster_fdd.core.artifact import CARD_FILE
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES
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

    def __post_init__(self) -> None:
        if not self.id.isidentifier():
            raise BadInputError(f"thruster id {self.id!r} must be a ROS name token like t0")
        for name in ("condition", "fault_condition"):
            value = getattr(self, name)
            if value is not None and value not in CLASS_NAMES:
                raise BadInputError(f"thruster {self.id}: unknown {name} {value!r}")
        if (self.fault_at_s is None) != (self.fault_condition is None):
            raise BadInputError(f"thruster {self.id}: a fault needs both a time and a condition")


@dataclass(frozen=True)
class ModelStage:
    """A node of the per-thruster pipeline that runs an exported model from ``folder``."""

    node: str
    folder: str


MODEL_STAGES = (ModelStage("nominal_model", "nominal"), ModelStage("classifier", "classifier"))


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd up``."""
    p.add_argument("--config", type=Path, help="YAML with rate_hz and a thrusters: list")
    p.add_argument("--thrusters", type=int, default=1, help="number of simulated thrusters")
    p.add_argument("--preset", default="t100", help="simulator preset or configuration YAML")
    p.add_argument("--rate", type=float, default=50.0, help="telemetry rate, Hz (10-100)")
    p.add_argument("--signal", default="mission", help="command signal of simulated thrusters")
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="ID:CONDITION@S",
        help="inject a condition into a simulated thruster at S seconds, e.g. t0:broken_blade_1@20",
    )
    p.add_argument("--duration", type=float, help="stop after this many seconds (default: Ctrl-C)")
    p.add_argument("--print-period", type=float, default=2.0, help="table refresh period, s")
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


def plan_from_args(args: argparse.Namespace) -> tuple[float, tuple[ThrusterPlan, ...]]:
    """The telemetry rate and the thrusters to run, from ``up``'s options or its --config."""
    if args.config is not None:
        spec: dict[str, Any] = yaml.safe_load(Path(args.config).read_text()) or {}
        rate = float(spec.get("rate_hz", args.rate))
        entries = spec.get("thrusters")
        if not isinstance(entries, list) or not entries:
            raise BadInputError(f"{args.config}: needs a non-empty 'thrusters:' list")
        known = set(ThrusterPlan.__dataclass_fields__)
        plans = []
        for entry in entries:
            unknown = set(entry) - known
            if unknown:
                raise BadInputError(f"{args.config}: unknown thruster key(s) {sorted(unknown)}")
            plans.append(ThrusterPlan(**entry))
    else:
        if args.thrusters < 1:
            raise BadInputError("--thrusters must be >= 1")
        rate = args.rate
        plans = [
            ThrusterPlan(id=f"t{i}", preset=args.preset, seed=i, signal=args.signal)
            for i in range(args.thrusters)
        ]
    if not 1.0 <= rate <= 1000.0:
        raise BadInputError(f"telemetry rate must be within 1..1000 Hz, got {rate}")
    by_id = {p.id: p for p in plans}
    if len(by_id) != len(plans):
        raise BadInputError("thruster ids must be unique")
    for text in args.fault:
        tid, _, rest = text.partition(":")
        condition, _, at = rest.partition("@")
        if tid not in by_id or not at:
            raise BadInputError(f"--fault {text!r}: expected ID:CONDITION@SECONDS with a known id")
        by_id[tid] = ThrusterPlan(
            **{**by_id[tid].__dict__, "fault_at_s": float(at), "fault_condition": condition}
        )
    return rate, tuple(by_id[p.id] for p in plans)


def _commands(plan: ThrusterPlan, rate: float, run_dir: Path) -> dict[str, list[str]]:
    ns = f"/thruster/{plan.id}"
    port = plan.port or str(run_dir / f"{plan.id}.tty")
    out: dict[str, list[str]] = {}
    if plan.port is None:
        emulate = [sys.executable, "-m", "thruster_fdd.cli", "emulate", "--link", port]
        emulate += ["--preset", plan.preset, "--condition", plan.condition]
        emulate += ["--rate", str(rate), "--seed", str(plan.seed), "--protocol", plan.protocol]
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
    models = (args.models or default_models_dir()).resolve()
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
