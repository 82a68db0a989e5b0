"""Container: nodes of one or more kinds, one of each per thruster, in a single process.

``thruster-fdd up`` runs the vehicle's nodes of all thrusters in one container — the ESC drivers
(lifecycle nodes sharing one serial reader thread), the nominal models and the classifiers — so
the interpreter, rclpy, the model code and numba's compiled kernels are loaded once, not once per
thruster and kind (about 60 MB for an rclpy process, 100 MB more for the models), and each
thruster's samples go from its driver to its nominal model to its classifier by direct calls
(intra-process delivery, ``--no-intra-process`` turns it off: the stages then subscribe over
DDS) — the ROS composition idea with plain rclpy. Every node keeps its own namespace
``/thruster/<id>``, its parameters and its services (``thruster-fdd reload`` and the lifecycle
services work the same). Parameters come from ``--ros-args --params-file FILE`` (the standard
``/thruster/<id>/<node>: ros__parameters:`` form) and ``-p [KIND:]name=value`` (which wins).

The executor is ``nodes.common.make_executor()``'s: one EventsExecutor for all nodes (it does
no work per entity on a wake), or with ``THRUSTER_FDD_EXECUTOR=single`` one SingleThreadedExecutor
per thruster, each in its own thread (``spin_in_threads``: rclpy rebuilds the wait set from every
entity of an executor's nodes on each wake).

With ``--vehicle health recorder`` the container also hosts the vehicle-wide nodes: the health
node takes every thruster's residuals and diagnoses by direct calls, and the recorder writes
what the nodes of this process publish (and the commands the drivers take) from the bytes they
publish, each message serialised once, by a writer thread (``core.traces.bag_writer``): nothing
of the process subscribes to its own 50 Hz topics over DDS. Other topics of the graph (e.g.
``/diagnostics``) the recorder takes over DDS, as the standalone recorder does.

Usage: ``python -m thruster_fdd.nodes.container KIND [KIND ...] --thrusters t0 t1
[--vehicle health recorder] [-p [KIND:]name=value ...] [--ros-args --params-file FILE]``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import threading
from collections.abc import Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.parameter import Parameter
from rclpy.utilities import remove_ros_args

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.names import check_thruster_id
from thruster_fdd.lifetime import stop_with_parent
from thruster_fdd.nodes.common import (
    BadParameterError,
    executor_kind,
    init_rclpy,
    make_executor,
    release_and_destroy,
    spin,
)

# Node kind -> (module, class) of the vehicle's nodes. Any other node class is named
# ``package.module:Class`` and hosted under its node name (the shore's command player is).
KINDS = {
    "esc_driver": ("thruster_fdd.nodes.esc_driver", "EscDriver"),
    "nominal_model": ("thruster_fdd.nodes.nominal_model", "NominalModelNode"),
    "classifier": ("thruster_fdd.nodes.classifier", "ClassifierNode"),
}
VEHICLE_KINDS = {
    "health": ("thruster_fdd.nodes.health", "HealthNode"),
    "recorder": ("thruster_fdd.nodes.recorder", "Recorder"),
}
"""Node kinds of which one runs per vehicle (``--vehicle``), not one per thruster."""


def node_class(kind: str) -> type:
    """The node class of ``kind``: a name of ``KINDS`` or ``package.module:Class``.

    Raises
    ------
    ValueError
        If ``kind`` is neither, or its module or class cannot be found.
    """
    if kind in KINDS or kind in VEHICLE_KINDS:
        module, cls_name = {**KINDS, **VEHICLE_KINDS}[kind]
    else:
        module, sep, cls_name = kind.partition(":")
        if not sep or not module or not cls_name:
            raise ValueError(f"{kind}: expected one of {sorted(KINDS)} or package.module:Class")
    try:
        return getattr(importlib.import_module(module), cls_name)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"{kind}: cannot load the node class ({exc})") from None


def _value(text: str) -> object:
    """Parse a ``-p`` value the way ROS parameter overrides read booleans and numbers."""
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            continue
    return text


def parse_parameters(kinds: list[str], texts: list[str]) -> dict[str, list[Parameter]]:
    """The parameter overrides of each kind from ``-p [KIND:]NAME=VALUE`` texts.

    Raises
    ------
    ValueError
        If a text has no ``=`` or names a kind not in ``kinds``.
    """
    params: dict[str, list[Parameter]] = {kind: [] for kind in kinds}
    for text in texts:
        key, eq, value = text.partition("=")
        target, _, name = key.rpartition(":")
        if not eq or not name:
            raise ValueError(f"-p {text}: expected [KIND:]NAME=VALUE")
        if target and target not in params:
            raise ValueError(f"-p {text}: {target} is not among the kinds {kinds}")
        for kind in [target] if target else kinds:
            params[kind].append(Parameter(name, value=_value(value)))
    return params


def main(argv: list[str] | None = None) -> None:
    """Create one node of each ``KIND`` per thruster and spin them all until Ctrl-C."""
    argv = sys.argv if argv is None else [sys.argv[0], *argv]
    parser = argparse.ArgumentParser(
        prog="container",
        description=__doc__.splitlines()[0],
        epilog="Each kind's parameters, with units, defaults and ranges: `<kind> --help` "
        "(ros2 run thruster_fdd esc_driver --help). A bad parameter is one line, exit 2.",
    )
    parser.add_argument(
        "kinds",
        nargs="+",
        metavar="KIND",
        help=f"node kinds: {', '.join(sorted(KINDS))}, or package.module:Class",
    )
    parser.add_argument(
        "--thrusters", nargs="+", required=True, metavar="ID", help="one node of each kind per id"
    )
    parser.add_argument(
        "--vehicle",
        nargs="+",
        default=[],
        choices=sorted(VEHICLE_KINDS),
        metavar="KIND",
        help="vehicle-wide nodes, one each: health (its thruster_ids are --thrusters), "
        "recorder (records what this process's nodes publish and take without subscribing to "
        "it, and every other topic of the graph over DDS)",
    )
    parser.add_argument(
        "--no-intra-process",
        dest="intra_process",
        action="store_false",
        help="each stage subscribes to the previous one's topic over DDS instead of taking "
        "its thruster's samples by a direct call in this process",
    )
    parser.add_argument(
        "-p",
        dest="params",
        action="append",
        default=[],
        metavar="[KIND:]NAME=VALUE",
        help="a parameter of every node of KIND (of every kind without it); wins over the "
        "parameters file",
    )
    args = parser.parse_args(remove_ros_args(argv)[1:])
    try:
        for tid in args.thrusters:
            check_thruster_id(tid)
    except BadInputError as exc:
        print(f"container {' '.join(args.kinds)}: {exc}", file=sys.stderr)
        sys.exit(2)
    try:
        params = parse_parameters([*args.kinds, *args.vehicle], args.params)
        kind = executor_kind()
        classes = {name: node_class(name) for name in args.kinds}
        vehicle_classes = {name: node_class(name) for name in args.vehicle}
    except ValueError as exc:
        parser.error(str(exc))
    stop_with_parent()
    try:
        init_rclpy(argv)
    except KeyboardInterrupt:
        rclpy.try_shutdown()
        return
    # events: one executor for everything; single: one per thruster, each in a thread.
    executors: list[Any] = [make_executor(kind)] if kind == "events" else []
    nodes = []
    stages: dict[str, dict[str, Any]] = {}
    try:
        for tid in args.thrusters:
            if kind != "events":
                executors.append(make_executor(kind))
            made = {}
            for name, node_cls in classes.items():
                overrides = [Parameter("thruster_id", value=tid), *params[name]]
                made[name] = node_cls(namespace=f"/thruster/{tid}", parameter_overrides=overrides)
                nodes.append(made[name])
                executors[-1].add_node(made[name])
            if args.intra_process:
                connect_stages(made)
            stages[tid] = made
        vehicle: dict[str, Any] = {}
        if vehicle_classes and kind != "events":
            executors.append(make_executor(kind))
        for name, node_cls in vehicle_classes.items():
            overrides = list(params[name])
            if name == "health":
                overrides.append(Parameter("thruster_ids", value=list(args.thrusters)))
            vehicle[name] = node_cls(parameter_overrides=overrides)
            nodes.append(vehicle[name])
            executors[-1].add_node(vehicle[name])
        if args.intra_process:
            # Health callbacks join the stages' thread only when one executor runs them all.
            connect_vehicle(vehicle, stages, direct_health=kind == "events")
        if len(executors) == 1:
            spin(executors[0])
        else:
            spin_in_threads(executors, [*args.thrusters, *(["vehicle"] if vehicle else [])])
    except BadParameterError as exc:
        print(f"container {' '.join(args.kinds)}: {exc}", file=sys.stderr)
        sys.exit(2)
    except ValueError as exc:
        print(f"container {' '.join(args.kinds)}: cannot start: {exc}", file=sys.stderr)
        sys.exit(1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        release_and_destroy(executors, nodes)
        rclpy.try_shutdown()


def connect_stages(nodes: dict[str, Any]) -> None:
    """Wire one thruster's stages in this process by direct calls (intra-process delivery):
    driver -> nominal model (telemetry), nominal model -> classifier (residuals)."""
    if {"esc_driver", "nominal_model"} <= nodes.keys():
        nodes["nominal_model"].take_telemetry_from(nodes["esc_driver"])
    if {"nominal_model", "classifier"} <= nodes.keys():
        nodes["classifier"].take_residuals_from(nodes["nominal_model"])


def connect_vehicle(
    vehicle: dict[str, Any], stages: dict[str, dict[str, Any]], direct_health: bool
) -> None:
    """Wire the vehicle-wide nodes to the thrusters' nodes of this process by direct calls:
    the health node takes residuals and diagnoses (``direct_health``), the recorder takes
    every message the others publish (and the commands the drivers take)."""
    health, recorder = vehicle.get("health"), vehicle.get("recorder")
    if health is not None and direct_health:
        for tid, made in stages.items():
            if "nominal_model" in made:
                health.take_from(tid, made["nominal_model"], made.get("classifier"))
    if recorder is None:
        return
    for node in [*(n for made in stages.values() for n in made.values()), health]:
        if node is not None and hasattr(node, "record_to"):
            recorder.take_local(node.record_to(recorder.record))


def spin_in_threads(executors: Sequence[Any], names: Sequence[str]) -> None:
    """Spin each executor in a thread of its own (``nodes.common.spin``) until Ctrl-C or
    shutdown.

    One SingleThreadedExecutor per thruster because rclpy rebuilds the wait set from every
    entity of an executor's nodes on each wake (with one executor for four thrusters, most of the
    container's CPU: ``docs/development.md``). The caller shuts the executors down.

    Raises
    ------
    KeyboardInterrupt
        On Ctrl-C.
    RuntimeError
        When a callback raised: the whole container stops, as with a single executor.
    """
    errors: list[tuple[str, BaseException]] = []

    def run(name: str, executor: Any) -> None:
        try:
            spin(executor)
        except ExternalShutdownException:
            pass
        except BaseException as exc:
            errors.append((name, exc))
            executor.context.try_shutdown()  # wakes every executor of the context: all end

    threads = [
        threading.Thread(target=run, args=(name, executor), name=f"spin-{name}")
        for name, executor in zip(names, executors, strict=True)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    if errors:
        name, exc = errors[0]
        raise RuntimeError(f"thruster {name}: a callback raised {exc!r}") from exc


if __name__ == "__main__":
    main()
