"""``thruster-fdd up``: the project's own launcher of the whole node set.

Processes (``process_commands``, the one place their command lines are built):

- ``vehicle``: one container (``nodes/container.py``) with every thruster's ESC driver (a
  lifecycle node), nominal model and classifier — what runs on a vehicle;
- ``recorder``: the MCAP recorder, restarted when it exits while the rest keeps running;
- the simulation harness, for simulated thrusters only: a microcontroller emulator per thruster
  on a pseudo-terminal (``thruster-fdd emulate``) and one container with their command players.

Every node's parameters go into one parameters file in the standard ROS form
(``/thruster/<id>/<node>: ros__parameters:``, ``node_parameters``), which the containers load
with ``--params-file``. ``up`` then drives the drivers' lifecycle through their services:
configure (ports opened) and activate (commands forwarded); on Ctrl-C or ``--duration`` it
deactivates them (neutral sent) and stops every child cleanly (SIGINT first). It prints a live
table meanwhile.
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
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import yaml

from thruster_fdd.commands.common import EXIT_FAILED, EXIT_OK
from thruster_fdd.core import atomic
from thruster_fdd.core.artifact import CARD_FILE
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES
from thruster_fdd.lifetime import child_env, node_command, stop_children, stop_with_parent

NAME = "up"
HELP = "start the node set on simulated (default) or real serial thrusters"
DESCRIPTION = (
    "Start the node set. Simulated thrusters (the default) each get a microcontroller emulator "
    "serving the bridge protocol on a pseudo-terminal and a command player; real thrusters "
    "(port: in --config) get none. One vehicle process hosts every thruster's ESC driver "
    "(configured and activated through its lifecycle services), nominal model and classifier; "
    "a recorder writes every topic to MCAP and is restarted if it exits. "
    "Prints a live table per thruster; Ctrl-C stops everything cleanly (neutral commands sent)."
)

DRIVER_SETTINGS = (
    "baud",
    "pole_pairs",
    "rate_hz",
    "command_rate_hz",
    "command_timeout_s",
    "max_command_rate_per_s",
    "bridge_timeout_ms",
)
"""ThrusterPlan fields that are ``esc_driver`` parameters of the same name (README, esc_driver)."""

LIFECYCLE_TIMEOUT_S = 60.0
"""Longest wait for the drivers' lifecycle services to appear and answer, s (the vehicle
process loads the models first)."""

RECORDER_BACKOFF_S = (1.0, 60.0)
"""Delay before the first restart of an exited recorder, and the longest (doubling), s."""


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
    baud, pole_pairs, rate_hz, command_rate_hz, command_timeout_s, max_command_rate_per_s,
    bridge_timeout_ms : number or None
        The thruster's ESC driver settings (``DRIVER_SETTINGS``, units as the driver's
        parameters); None keeps the driver's default, and ``rate_hz`` None is ``up``'s rate
        (also the rate of a simulated thruster's emulator).
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
    baud: int | None = None
    pole_pairs: int | None = None
    rate_hz: float | None = None
    command_rate_hz: float | None = None
    command_timeout_s: float | None = None
    max_command_rate_per_s: float | None = None
    bridge_timeout_ms: int | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not self.id.isidentifier():
            raise BadInputError(f"thruster id {self.id!r} must be a ROS name token like t0")
        for name in ("condition", "fault_condition"):
            value = getattr(self, name)
            if value is not None and value not in CLASS_NAMES:
                raise BadInputError(f"thruster {self.id}: unknown {name} {value!r}")
        if (self.fault_at_s is None) != (self.fault_condition is None):
            raise BadInputError(f"thruster {self.id}: a fault needs both a time and a condition")
        if self.protocol not in ("tfdd", "kiss"):
            raise BadInputError(f"thruster {self.id}: protocol must be tfdd or kiss")
        for name in DRIVER_SETTINGS:
            value = getattr(self, name)
            integral = name in ("baud", "pole_pairs", "bridge_timeout_ms")
            allowed = (int,) if integral else (int, float)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, allowed):
                kind = "an integer" if integral else "a number"
                raise BadInputError(f"thruster {self.id}: {name} must be {kind}, got {value!r}")
            lowest_ok = name in ("max_command_rate_per_s", "bridge_timeout_ms")
            if not math.isfinite(value) or value < 0 or (value == 0 and not lowest_ok):
                raise BadInputError(f"thruster {self.id}: {name} must be > 0, got {value}")

    def driver_settings(self) -> dict[str, int | float]:
        """The driver settings this plan sets (``DRIVER_SETTINGS`` that are not None)."""
        return {n: getattr(self, n) for n in DRIVER_SETTINGS if getattr(self, n) is not None}


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
    p.add_argument(
        "--executor",
        choices=("events", "single"),
        help="executor of every node process: events (rclpy's EventsExecutor, the default) or "
        "single (SingleThreadedExecutor, the fallback; default: $THRUSTER_FDD_EXECUTOR)",
    )


def plan_from_args(args: argparse.Namespace) -> tuple[float, tuple[ThrusterPlan, ...]]:
    """The telemetry rate and the thrusters to run, from ``up``'s options or its --config."""
    if args.config is not None:
        spec: dict[str, Any] = yaml.safe_load(Path(args.config).read_text()) or {}
        rate = float(spec.get("rate_hz", args.rate))
        entries = spec.get("thrusters")
        if not isinstance(entries, list) or not entries:
            raise BadInputError(f"{args.config}: needs a non-empty 'thrusters:' list")
        known = {f.name for f in fields(ThrusterPlan)}
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
    ports = [p.port for p in plans if p.port is not None]
    if len(set(ports)) != len(ports):
        raise BadInputError("serial ports must be unique: one driver per port")
    for text in args.fault:
        tid, _, rest = text.partition(":")
        condition, _, at = rest.partition("@")
        if tid not in by_id or not at:
            raise BadInputError(f"--fault {text!r}: expected ID:CONDITION@SECONDS with a known id")
        by_id[tid] = ThrusterPlan(
            **{**by_id[tid].__dict__, "fault_at_s": float(at), "fault_condition": condition}
        )
    return rate, tuple(by_id[p.id] for p in plans)


def exported_stages(models: Path) -> tuple[ModelStage, ...]:
    """The model stages whose model is exported in ``models``."""
    return tuple(st for st in MODEL_STAGES if (models / st.folder / CARD_FILE).is_file())


def node_parameters(
    plans: tuple[ThrusterPlan, ...], rate: float, run_dir: Path, models: Path
) -> dict[str, dict[str, Any]]:
    """Every node's parameters by fully qualified node name (the parameters file's content).

    Simulated thrusters' ports are pseudo-terminals in ``run_dir``.
    """
    params: dict[str, dict[str, Any]] = {}
    stages = exported_stages(models)
    for plan in plans:
        ns = f"/thruster/{plan.id}"
        params[f"{ns}/esc_driver"] = {
            "thruster_id": plan.id,
            "port": plan.port or str(run_dir / f"{plan.id}.tty"),
            "protocol": plan.protocol,
            "rate_hz": float(plan.rate_hz or rate),
            **plan.driver_settings(),
        }
        for stage in stages:
            params[f"{ns}/{stage.node}"] = {
                "thruster_id": plan.id,
                "model_dir": str(models / stage.folder),
            }
        if plan.port is None:
            params[f"{ns}/command_player"] = {"signal": plan.signal, "seed": plan.seed}
    return params


def write_parameters(params: dict[str, dict[str, Any]], path: Path) -> None:
    """Write ``params`` as a ROS parameters file (``node: ros__parameters: {...}``)."""
    text = yaml.safe_dump(
        {node: {"ros__parameters": values} for node, values in params.items()}, sort_keys=False
    )
    atomic.write_text(path, text)


def process_commands(
    plans: tuple[ThrusterPlan, ...], rate: float, run_dir: Path, models: Path, params_file: Path
) -> dict[str, list[str]]:
    """The command line of every process but the recorder (``recorder_command``), by name.

    ``vehicle``: one container with every thruster's driver and the exported model stages.
    Per simulated thruster an emulator ``<id>-emulator``; one ``commands`` container with their
    command players.
    """
    ids = [p.id for p in plans]
    ros_args = ["--ros-args", "--params-file", str(params_file)]
    container = [sys.executable, "-m", "thruster_fdd.nodes.container"]
    kinds = ["esc_driver", *(st.node for st in exported_stages(models))]
    out = {"vehicle": [*container, *kinds, "--thrusters", *ids, *ros_args]}
    simulated = [p for p in plans if p.port is None]
    for plan in simulated:
        emulate = [sys.executable, "-m", "thruster_fdd.cli", "emulate"]
        emulate += ["--link", str(run_dir / f"{plan.id}.tty")]
        emulate += ["--preset", plan.preset, "--condition", plan.condition]
        emulate += ["--rate", str(plan.rate_hz or rate), "--seed", str(plan.seed)]
        emulate += ["--protocol", plan.protocol]
        if plan.fault_at_s is not None and plan.fault_condition is not None:
            emulate += ["--fault-at", str(plan.fault_at_s)]
            emulate += ["--fault-condition", plan.fault_condition]
        out[f"{plan.id}-emulator"] = emulate
    if simulated:
        out["commands"] = [
            *container,
            "command_player",
            "--thrusters",
            *(p.id for p in simulated),
            *ros_args,
        ]
    return out


def recorder_command(record_dir: Path, prefix: str, models: Path) -> list[str]:
    """The recorder's command line: every topic to ``record_dir/<prefix>_*.mcap``."""
    model_ids = ",".join(
        f"{stage.folder}={json.loads((models / stage.folder / CARD_FILE).read_text())['model_id']}"
        for stage in exported_stages(models)
    )
    return node_command(
        "recorder",
        "/",
        {"output_dir": record_dir.resolve(), "prefix": prefix, "model_ids": f"'{model_ids}'"},
    )


def _start(cmd: list[str], log: Path, env: dict[str, str]) -> subprocess.Popen[bytes]:
    # Own process group: a Ctrl-C reaches children only through stop_children, so they stop in
    # order after the table's last print.
    with log.open("ab") as out:
        return subprocess.Popen(
            cmd, stdout=out, stderr=subprocess.STDOUT, start_new_session=True, env=env
        )


def run(args: argparse.Namespace) -> int:
    """Start the node set, print the live table, stop everything on Ctrl-C or --duration."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from thruster_fdd.core.artifact import default_models_dir
    from thruster_fdd.nodes.common import EXECUTOR_ENV, executor_kind, make_executor, spin_until
    from thruster_fdd.nodes.lifecycle_client import change_states
    from thruster_fdd.nodes.monitor import Monitor

    rate, plans = plan_from_args(args)
    models = (args.models or default_models_dir()).resolve()
    run_dir = Path(tempfile.mkdtemp(prefix="thruster_fdd-up-"))
    params_file = run_dir / "params.yaml"
    write_parameters(node_parameters(plans, rate, run_dir, models), params_file)
    env = child_env()
    try:
        env[EXECUTOR_ENV] = args.executor or executor_kind()
    except ValueError as exc:
        raise BadInputError(str(exc)) from None
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    stop_with_parent()

    children: dict[str, subprocess.Popen[bytes]] = {}
    drivers = [f"/thruster/{p.id}/esc_driver" for p in plans]
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    monitor = Monitor([p.id for p in plans])
    executor = make_executor(env[EXECUTOR_ENV])
    executor.add_node(monitor)
    prefix = f"up_{time.strftime('%Y%m%d_%H%M%S')}"
    recorder_restarts = 0
    try:
        # The recorder starts first, so it is listening when the first telemetry comes.
        if not args.no_record:
            children["recorder"] = _start(
                recorder_command(args.record_dir, prefix, models), run_dir / "recorder.log", env
            )
        for name, cmd in process_commands(plans, rate, run_dir, models, params_file).items():
            children[name] = _start(cmd, run_dir / f"{name}.log", env)
        kinds = ", ".join(
            f"{p.id}: {'serial ' + p.port if p.port else 'simulated ' + p.preset}" for p in plans
        )
        print(f"thruster-fdd up: {len(plans)} thruster(s) at {rate:g} Hz ({kinds})")
        domain = os.environ.get("ROS_DOMAIN_ID", 0)
        print(f"ports, parameters and logs: {run_dir}   (ROS_DOMAIN_ID={domain})")
        stages = [f"{st.node} ({models / st.folder})" for st in exported_stages(models)]
        print(f"models: {', '.join(stages) if stages else f'none in {models}'}")
        if not args.no_record:
            print(f"recording every topic to {args.record_dir.resolve()}/{prefix}_*.mcap")
        for transition in ("configure", "activate"):
            problems = change_states(monitor, executor, drivers, transition, LIFECYCLE_TIMEOUT_S)
            if problems:
                for target, why in problems.items():
                    print(f"thruster-fdd up: {target}: {why}; see {run_dir}", file=sys.stderr)
                return EXIT_FAILED
        print("Ctrl-C stops" if args.duration is None else f"running for {args.duration:g} s")
        start = time.monotonic()
        next_print = start + args.print_period
        restart_at: float | None = None
        while not stop.is_set():
            spin_until(executor, stop.is_set, time.monotonic() + 0.05)
            now = time.monotonic()
            if args.duration is not None and now - start >= args.duration:
                break
            if now >= next_print:
                next_print += args.print_period
                print(f"\n[t = {now - start:5.1f} s]\n{monitor.table()}", flush=True)
            recorder = children.get("recorder")
            if recorder is not None and recorder.poll() is not None and restart_at is None:
                recorder_restarts += 1
                first, longest = RECORDER_BACKOFF_S
                delay = min(longest, first * 2 ** (recorder_restarts - 1))
                restart_at = now + delay
                print(
                    f"thruster-fdd up: the recorder exited (code {recorder.returncode}); "
                    f"restart {recorder_restarts} in {delay:g} s (see {run_dir}/recorder.log)",
                    file=sys.stderr,
                    flush=True,
                )
            if restart_at is not None and now >= restart_at:
                restart_at = None
                restarted = f"{prefix}_r{recorder_restarts}"
                children["recorder"] = _start(
                    recorder_command(args.record_dir, restarted, models),
                    run_dir / "recorder.log",
                    env,
                )
                print(f"recording to {args.record_dir.resolve()}/{restarted}_*.mcap", flush=True)
            dead = [n for n, p in children.items() if n != "recorder" and p.poll() is not None]
            if dead:
                print(f"thruster-fdd up: {', '.join(dead)} exited; see {run_dir}", file=sys.stderr)
                return EXIT_FAILED
        print(f"\nfinal:\n{monitor.table()}")
        return EXIT_OK
    finally:
        if children.get("vehicle") is not None and children["vehicle"].poll() is None:
            # Neutral to every bridge before the processes stop (they send it again on exit).
            change_states(monitor, executor, drivers, "deactivate", 5.0)
        stop_children(children, timeout_s=5.0)
        executor.shutdown()
        monitor.destroy_node()
        rclpy.try_shutdown()
