"""``thruster-fdd up``: the project's own launcher of the whole node set.

Processes (``process_commands``, the one place their command lines are built):

- ``vehicle``: one container (``nodes/container.py``) with every thruster's ESC driver (a
  lifecycle node), nominal model and classifier, the health node and the recorder — what runs
  on a vehicle; the recorder writes what the vehicle's nodes publish from the bytes they publish
  (a writer thread, retrying after disk errors), and takes the rest of the graph over DDS;
- the simulation harness, for simulated thrusters only: a microcontroller emulator per thruster
  on a pseudo-terminal (``thruster-fdd emulate``) and one container with their command players.

Every node's parameters go into one parameters file in the standard ROS form
(``/thruster/<id>/<node>: ros__parameters:``, ``node_parameters``), which the containers load
with ``--params-file``. ``up`` then drives the drivers' lifecycle through their services:
configure (ports opened), a wait until the recorder reports every thruster's telemetry,
residual and diagnosis topics (so the bag starts with the first sample the live models use),
and activate (commands forwarded); on Ctrl-C or ``--duration`` it
deactivates them (neutral sent) and stops every child cleanly (SIGINT first). It prints a live
table meanwhile, from the nodes' once-a-second statuses on ``/diagnostics``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import typing
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from types import UnionType
from typing import Any

from thruster_fdd.core import atomic
from thruster_fdd.core.artifact import CARD_FILE
from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.labels import CLASS_NAMES
from thruster_fdd.core.names import check_thruster_id
from thruster_fdd.core.safe_yaml import dump_yaml, load_yaml
from thruster_fdd.lifetime import child_env, stop_children, stop_with_parent
from thruster_fdd_shore.commands.common import (
    EXIT_FAILED,
    EXIT_OK,
    check_models,
    check_output,
    positive_float,
)
from thruster_fdd_shore.commands.emulate import BRIDGES
from thruster_fdd_shore.core.sim.signals import make_signal

NAME = "up"
HELP = "start the node set on simulated (default) or real serial thrusters"
DESCRIPTION = (
    "Start the node set. Simulated thrusters (the default) each get a microcontroller emulator "
    "serving the bridge protocol on a pseudo-terminal and a command player; real thrusters "
    "(port: in --config) get none. One vehicle process hosts every thruster's ESC driver "
    "(configured and activated through its lifecycle services), nominal model and classifier, "
    "the health node and the recorder, which writes every topic to MCAP. "
    "Prints a live table per thruster; Ctrl-C stops everything cleanly (neutral commands sent). "
    "One up per ROS domain: it refuses a domain where another up, or a node of the names it "
    "starts, runs."
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

RECORDER_MATCH_TIMEOUT_S = 30.0
"""Longest wait, after *configure*, for the recorder to report every thruster's telemetry,
residual and diagnosis topics before the drivers are activated, s."""

RECORDED_TOPICS = ("esc/telemetry", "fdd/residual", "fdd/diagnosis")
"""Per-thruster topics the recorder must report before the drivers publish: the bag then
holds every sample the live models used, so ``replay`` and ``diagnose`` reproduce them."""

NEIGHBOUR_DISCOVERY_S = 6.0
"""How long ``up`` listens on its ROS domain for nodes of the names it would start before it
starts any, s, counted from when its own node joins (the input checks run meanwhile). Node
names of a graph that other processes just left can take over 3 s to arrive."""

UP_NODE = "thruster_fdd_up"
"""The name of ``up``'s own node (the live table's), by which a second ``up`` finds it."""


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
    bridge: str = "python"
    baud: int | None = None
    pole_pairs: int | None = None
    rate_hz: float | None = None
    command_rate_hz: float | None = None
    command_timeout_s: float | None = None
    max_command_rate_per_s: float | None = None
    bridge_timeout_ms: int | None = None

    def __post_init__(self) -> None:
        check_thruster_id(self.id)
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
        for name in DRIVER_SETTINGS:
            value = getattr(self, name)
            integral = name in ("baud", "pole_pairs", "bridge_timeout_ms")
            allowed = (int,) if integral else (int, float)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, allowed):
                kind = "an integer" if integral else "a number"
                raise BadInputError(f"thruster {self.id}: {name} must be {kind}, got {value!r}")
            low, high = driver_limits()[name]
            if not low <= value <= high:
                raise BadInputError(
                    f"thruster {self.id}: {name} must be within {low:g}..{high:g} (the "
                    f"esc_driver's range), got {value:g}"
                )

    def driver_settings(self) -> dict[str, int | float]:
        """The driver settings this plan sets (``DRIVER_SETTINGS`` that are not None)."""
        return {n: getattr(self, n) for n in DRIVER_SETTINGS if getattr(self, n) is not None}


def driver_limits() -> dict[str, tuple[float, float]]:
    """The esc_driver's declared ranges of the ``DRIVER_SETTINGS`` (``esc_driver.LIMITS``, the
    ones its parameter descriptors and its configure check use), imported when first needed."""
    from thruster_fdd.nodes.esc_driver import LIMITS

    return {name: LIMITS[name] for name in DRIVER_SETTINGS}  # type: ignore[misc]


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
    p.add_argument(
        "--keep-run-dir",
        action="store_true",
        help="keep the run folder (ports, parameters, logs) after a clean exit; it is always "
        "kept, and named, after a failure",
    )
    p.add_argument(
        "--executor",
        choices=("events", "single"),
        help="executor of every node process: events (rclpy's EventsExecutor, the default) or "
        "single (SingleThreadedExecutor, the fallback; default: $THRUSTER_FDD_EXECUTOR)",
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
    devices: dict[str, str] = {}
    for plan in plans:
        if plan.port is None:
            continue
        # The real device: a symlink (/dev/serial/by-id/...) and its target are one port.
        device = os.path.realpath(plan.port)
        if device in devices:
            raise BadInputError(
                f"thrusters {devices[device]} and {plan.id} use the same serial device {device}: "
                "one driver per port"
            )
        devices[device] = plan.id
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
    from thruster_fdd_shore.core.sim.config import load_config

    for preset in sorted({p.preset for p in plans if p.port is None}):
        load_config(preset)
    if not args.no_record:
        check_output(args.record_dir, "--record-dir", folder=True)
    if (models / "nominal" / CARD_FILE).is_file():
        check_models(models)


def health_reference(models: Path, preset: str) -> Path:
    """The reference folder for the health node: the models folder's ``reference/`` when it was
    computed from ``preset``'s configuration, else one computed now into the user's cache
    (``$XDG_CACHE_HOME/thruster_fdd/reference/``, once per configuration: about 30 s)."""
    from thruster_fdd.core.artifact import read_card
    from thruster_fdd.core.diagnosis.reference import REFERENCE_KIND, ReferenceCard
    from thruster_fdd.core.errors import ModelMismatchError
    from thruster_fdd_shore.core.reference import (
        DEFAULT_VOLTAGES_V,
        config_digest,
        export_reference,
        voltage_grid,
    )
    from thruster_fdd_shore.core.sim.config import load_config

    config = load_config(preset)
    digest = config_digest(config)
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    for folder in (models / "reference", cache / "thruster_fdd" / "reference" / digest[:16]):
        try:
            card = read_card(folder, ReferenceCard, REFERENCE_KIND)
        except ModelMismatchError:
            continue
        if card.extra.get("config_digest") == digest:
            return folder
    print(f"[up] computing the reference load curves of {preset} (once: about 30 s)")
    export_reference(config, Path(preset).stem, folder, voltage_grid(*DEFAULT_VOLTAGES_V))
    return folder


def exported_stages(models: Path) -> tuple[ModelStage, ...]:
    """The model stages whose model is exported in ``models``."""
    return tuple(st for st in MODEL_STAGES if (models / st.folder / CARD_FILE).is_file())


def node_parameters(
    plans: tuple[ThrusterPlan, ...],
    rate: float,
    run_dir: Path,
    models: Path,
    reference: Path | None = None,
    record: tuple[Path, str] | None = None,
) -> dict[str, dict[str, Any]]:
    """Every node's parameters by fully qualified node name (the parameters file's content).

    Simulated thrusters' ports are pseudo-terminals in ``run_dir``; the health node's reference
    load curves are ``reference``; ``record`` is the recorder's (folder, bag prefix).
    """
    params: dict[str, dict[str, Any]] = {}
    if reference is not None:
        params["/health"] = {"reference": str(reference)}
    if record is not None:
        model_ids = ",".join(
            f"{st.folder}={json.loads((models / st.folder / CARD_FILE).read_text())['model_id']}"
            for st in exported_stages(models)
        )
        params["/recorder"] = {
            "output_dir": str(record[0].resolve()),
            "prefix": record[1],
            "model_ids": model_ids,
        }
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
    text = dump_yaml({node: {"ros__parameters": values} for node, values in params.items()})
    atomic.write_text(path, text)


def process_commands(
    plans: tuple[ThrusterPlan, ...],
    rate: float,
    run_dir: Path,
    models: Path,
    params_file: Path,
    record: bool,
) -> dict[str, list[str]]:
    """The command line of every process, by name.

    ``vehicle``: one container with every thruster's driver and the exported model stages, the
    health node and (``record``) the recorder. Per simulated thruster an emulator
    ``<id>-emulator`` (the Python emulator or the bridge firmware); one ``commands`` container
    with their command players.
    """
    ids = [p.id for p in plans]
    ros_args = ["--ros-args", "--params-file", str(params_file)]
    container = [sys.executable, "-m", "thruster_fdd.nodes.container"]
    kinds = ["esc_driver", *(st.node for st in exported_stages(models))]
    vehicle = ["--vehicle", "health", *(["recorder"] if record else [])]
    out = {"vehicle": [*container, *kinds, "--thrusters", *ids, *vehicle, *ros_args]}
    simulated = [p for p in plans if p.port is None]
    for plan in simulated:
        emulate = [sys.executable, "-m", "thruster_fdd_shore.cli", "emulate"]
        emulate += ["--link", str(run_dir / f"{plan.id}.tty")]
        emulate += ["--preset", plan.preset, "--condition", plan.condition]
        emulate += ["--rate", str(plan.rate_hz or rate), "--seed", str(plan.seed)]
        emulate += ["--protocol", plan.protocol, "--bridge", plan.bridge]
        if plan.fault_at_s is not None and plan.fault_condition is not None:
            emulate += ["--fault-at", str(plan.fault_at_s)]
            emulate += ["--fault-condition", plan.fault_condition]
        out[f"{plan.id}-emulator"] = emulate
    if simulated:
        out["commands"] = [
            *container,
            "thruster_fdd_shore.nodes.command_player:CommandPlayer",
            "--thrusters",
            *(p.id for p in simulated),
            *ros_args,
        ]
    return out


def _start(cmd: list[str], log: Path, env: dict[str, str]) -> subprocess.Popen[bytes]:
    # Own process group: a Ctrl-C reaches children only through stop_children, so they stop in
    # order after the table's last print.
    with log.open("ab") as out:
        return subprocess.Popen(
            cmd, stdout=out, stderr=subprocess.STDOUT, start_new_session=True, env=env
        )


def node_names(plans: tuple[ThrusterPlan, ...], models: Path, record: bool) -> list[str]:
    """The fully qualified names of the nodes ``up`` starts (its own ``UP_NODE`` first)."""
    names = [f"/{UP_NODE}", "/health", *(["/recorder"] if record else [])]
    for plan in plans:
        ns = f"/thruster/{plan.id}"
        names += [f"{ns}/esc_driver", *(f"{ns}/{st.node}" for st in exported_stages(models))]
        if plan.port is None:
            names.append(f"{ns}/command_player")
    return names


def shared_names(node: Any, names: list[str], ours: set[str]) -> list[str]:
    """The names among ``names`` that a node on the ROS domain holds besides ours: a name in
    ``ours`` is held by one node of ours, so it counts when two or more hold it."""
    counts = Counter(node.get_fully_qualified_node_names())
    return [name for name in names if counts[name] > (1 if name in ours else 0)]


def run(args: argparse.Namespace) -> int:
    """Start the node set, print the live table, stop everything on Ctrl-C or --duration.

    One ``up`` per ROS domain: before it starts any process it listens for
    ``NEIGHBOUR_DISCOVERY_S`` and refuses (exit 2) when a node of a name it would start, or
    another ``up``, is on the domain. It drives the lifecycle of the drivers of the vehicle
    process it started only, while that process runs and no other node has a driver's name;
    every wait ends at once on Ctrl-C or when a child exits.
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from thruster_fdd.core.artifact import default_models_dir
    from thruster_fdd.nodes.common import EXECUTOR_ENV, executor_kind, make_executor, spin_until
    from thruster_fdd_shore.nodes.lifecycle_client import change_states
    from thruster_fdd_shore.nodes.monitor import Monitor

    rate, plans = plan_from_args(args)
    if any(p.bridge == "firmware" for p in plans):
        from thruster_fdd_shore.core.bridge.firmware_build import ensure_built

        # Once here rather than in every emulator at once.
        ensure_built("hott")
    models = (args.models or default_models_dir()).resolve()
    env = child_env()
    try:
        env[EXECUTOR_ENV] = args.executor or executor_kind()
    except ValueError as exc:
        raise BadInputError(str(exc)) from None
    domain = os.environ.get("ROS_DOMAIN_ID", "0")
    children: dict[str, subprocess.Popen[bytes]] = {}
    drivers = [f"/thruster/{p.id}/esc_driver" for p in plans]
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    # Up's own node, named UP_NODE: it is on the domain before any child starts, so of two ups
    # started together each finds the other.
    monitor = Monitor([p.id for p in plans], UP_NODE)
    executor: Any = None  # made after the input checks
    listen_until = time.monotonic() + NEIGHBOUR_DISCOVERY_S
    stop = threading.Event()
    run_dir: Path | None = None
    activating = False  # from the first activate request on, drivers may be active
    clean = False  # the run folder is removed only after a clean run

    def interrupted() -> str | None:
        """Why the waiting must end now: a stop request, a dead child, a driver's name that
        another node on the domain has too (its services would reach both)."""
        if stop.is_set():
            return "stopped"
        dead = sorted(n for n, p in children.items() if p.poll() is not None)
        if dead:
            return f"{', '.join(dead)} exited"
        shared = shared_names(monitor, drivers, set(drivers))
        if shared:
            return f"another node named {shared[0]} is on ROS_DOMAIN_ID={domain}"
        return None

    try:
        # The checks run while DDS discovers the domain's nodes.
        _check_inputs(args, plans, models)
        reference = health_reference(models, plans[0].preset)
        executor = make_executor(env[EXECUTOR_ENV])
        executor.add_node(monitor)
        names = node_names(plans, models, not args.no_record)
        ours = {names[0]}
        spin_until(executor, lambda: bool(shared_names(monitor, names, ours)), listen_until)
        taken = shared_names(monitor, names, ours)
        if taken:
            raise BadInputError(
                f"ROS_DOMAIN_ID={domain} already has {', '.join(taken)}: another thruster-fdd "
                "up (or the launch file) runs there; stop it or give this one another "
                "ROS_DOMAIN_ID"
            )
        run_dir = Path(tempfile.mkdtemp(prefix="thruster_fdd-up-"))
        params_file = run_dir / "params.yaml"
        prefix = f"up_{time.strftime('%Y%m%d_%H%M%S')}"
        record = None if args.no_record else (args.record_dir, prefix)
        write_parameters(
            node_parameters(plans, rate, run_dir, models, reference, record), params_file
        )
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, lambda *_: stop.set())
        stop_with_parent()
        commands = process_commands(plans, rate, run_dir, models, params_file, record is not None)
        for name, cmd in commands.items():
            children[name] = _start(cmd, run_dir / f"{name}.log", env)
        kinds = ", ".join(
            f"{p.id}: {'serial ' + p.port if p.port else 'simulated ' + p.preset}" for p in plans
        )
        print(f"thruster-fdd up: {len(plans)} thruster(s) at {rate:g} Hz ({kinds})")
        print(f"ports, parameters and logs: {run_dir}   (ROS_DOMAIN_ID={domain})")
        stages = [f"{st.node} ({models / st.folder})" for st in exported_stages(models)]
        print(f"models: {', '.join(stages) if stages else f'none in {models}'}")
        cut_short: str | None = None
        for transition in ("configure", "activate"):
            activating = activating or transition == "activate"
            problems = change_states(
                monitor, executor, drivers, transition, LIFECYCLE_TIMEOUT_S, interrupted
            )
            cut_short = interrupted()
            if cut_short is not None:
                break
            if problems:
                for target, why in problems.items():
                    print(f"thruster-fdd up: {target}: {why}; see {run_dir}", file=sys.stderr)
                return EXIT_FAILED
            if transition == "configure" and not args.no_record:
                # Nothing is published before activate: wait for the recorder to report the
                # topics, so the bag starts with the first sample the live models use.
                wanted = {f"/thruster/{p.id}/{topic}" for p in plans for topic in RECORDED_TOPICS}
                deadline = time.monotonic() + RECORDER_MATCH_TIMEOUT_S

                def ready(wanted: set[str] = wanted) -> bool:
                    return interrupted() is not None or wanted <= monitor.recorder_matched

                matched = spin_until(executor, ready, deadline)
                cut_short = interrupted()
                if cut_short is not None:
                    break
                # The folder the recorder made: <prefix>, or <prefix>_2... when that was taken.
                bag = monitor.recorder_bag or (
                    f"{args.record_dir.resolve() / prefix} (not yet confirmed by the recorder)"
                )
                print(f"recording every topic to the bag {bag}")
                if not matched:
                    missing = ", ".join(sorted(wanted - monitor.recorder_matched))
                    print(
                        f"thruster-fdd up: the recorder has not matched {missing} after "
                        f"{RECORDER_MATCH_TIMEOUT_S:g} s; the bag may miss the first samples "
                        f"(see {run_dir}/vehicle.log)",
                        file=sys.stderr,
                    )
        if cut_short is not None:
            # A stop request ends the run as cleanly as after the table; a dead child is a
            # failure (the main loop's rule).
            clean = stop.is_set()
            print(f"thruster-fdd up: {cut_short} before the drivers were active", file=sys.stderr)
            return EXIT_OK if clean else EXIT_FAILED
        print("Ctrl-C stops" if args.duration is None else f"running for {args.duration:g} s")
        start = time.monotonic()
        next_print = start + args.print_period
        while not stop.is_set():
            spin_until(executor, stop.is_set, time.monotonic() + 0.05)
            now = time.monotonic()
            if args.duration is not None and now - start >= args.duration:
                break
            if now >= next_print:
                next_print += args.print_period
                print(f"\n[t = {now - start:5.1f} s]\n{monitor.table()}", flush=True)
            dead = [n for n, p in children.items() if p.poll() is not None]
            if dead:
                print(f"thruster-fdd up: {', '.join(dead)} exited; see {run_dir}", file=sys.stderr)
                return EXIT_FAILED
        print(f"\nfinal:\n{monitor.table()}")
        clean = True
        return EXIT_OK
    finally:
        vehicle = children.get("vehicle")
        if activating and vehicle is not None and vehicle.poll() is None:
            # Neutral to every bridge before the processes stop (they send it again on exit);
            # not through a name another node has too, whose services would reach both.
            shared = shared_names(monitor, drivers, set(drivers))
            if shared:
                print(
                    f"thruster-fdd up: not deactivating {', '.join(shared)}: another node of "
                    f"that name is on ROS_DOMAIN_ID={domain} (ours send neutral as they stop)",
                    file=sys.stderr,
                )
            change_states(
                monitor,
                executor,
                [d for d in drivers if d not in shared],
                "deactivate",
                5.0,
                lambda: None if vehicle.poll() is None else "the vehicle process exited",
            )
        stop_children(children, timeout_s=5.0)
        if executor is not None:
            executor.shutdown()
        monitor.destroy_node()
        rclpy.try_shutdown()
        if run_dir is not None and clean and not getattr(args, "keep_run_dir", False):
            shutil.rmtree(run_dir, ignore_errors=True)
        elif run_dir is not None:
            print(f"thruster-fdd up: ports, parameters and logs kept in {run_dir}", file=sys.stderr)
