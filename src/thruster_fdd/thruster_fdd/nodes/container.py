"""Container: nodes of one or more kinds, one of each per thruster, in a single process.

``thruster-fdd up`` runs both model stages (``nominal_model``, ``classifier``) of all thrusters
in one container, so the model code and numba's compiled kernels are loaded once, not once per
thruster and stage (about 100 MB each), and each thruster's classifier gets its residuals
straight from its nominal model in the process (intra-process delivery, ``--no-intra-process``
turns it off) — the ROS composition idea with plain rclpy. Every node keeps its own namespace
``/thruster/<id>``, its parameters and its parameter services (``thruster-fdd reload`` works the
same), and each thruster's nodes are spun by an executor thread of their own
(``spin_in_threads``).

Usage: ``python -m thruster_fdd.nodes.container KIND [KIND ...] --thrusters t0 t1
[-p [KIND:]name=value ...]``; a ``KIND:`` prefix gives the parameter to that kind's nodes only.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import threading
from collections.abc import Sequence

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.parameter import Parameter

from thruster_fdd.lifetime import stop_with_parent
from thruster_fdd.nodes.common import release_and_destroy

# Node kind -> (module, class) under thruster_fdd.nodes.
KINDS = {
    "esc_driver": ("esc_driver", "EscDriver"),
    "command_player": ("command_player", "CommandPlayer"),
    "nominal_model": ("nominal_model", "NominalModelNode"),
    "classifier": ("classifier", "ClassifierNode"),
}


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
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("kinds", nargs="+", choices=sorted(KINDS), metavar="KIND")
    parser.add_argument("--thrusters", nargs="+", required=True, metavar="ID")
    parser.add_argument(
        "--no-intra-process",
        dest="intra_process",
        action="store_false",
        help="classifiers subscribe to fdd/residual over DDS instead of taking the residuals "
        "of the nominal model of their thruster in this process",
    )
    parser.add_argument(
        "-p", dest="params", action="append", default=[], metavar="[KIND:]NAME=VALUE"
    )
    args = parser.parse_args(argv)
    try:
        params = parse_parameters(args.kinds, args.params)
    except ValueError as exc:
        parser.error(str(exc))
    classes = {}
    for kind in args.kinds:
        module, cls_name = KINDS[kind]
        classes[kind] = getattr(importlib.import_module(f"thruster_fdd.nodes.{module}"), cls_name)
    stop_with_parent()
    rclpy.init()
    executors: list[SingleThreadedExecutor] = []
    nodes = []
    try:
        for tid in args.thrusters:
            executor = SingleThreadedExecutor()
            executors.append(executor)
            made = {}
            for kind, node_cls in classes.items():
                overrides = [Parameter("thruster_id", value=tid), *params[kind]]
                made[kind] = node_cls(namespace=f"/thruster/{tid}", parameter_overrides=overrides)
                nodes.append(made[kind])
                executor.add_node(made[kind])
            if args.intra_process and {"nominal_model", "classifier"} <= made.keys():
                made["classifier"].take_residuals_from(made["nominal_model"])
        spin_in_threads(executors, args.thrusters)
    except ValueError as exc:
        print(f"container {' '.join(args.kinds)}: cannot start: {exc}", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt:
        pass
    finally:
        release_and_destroy(executors, nodes)
        rclpy.try_shutdown()


def spin_in_threads(executors: Sequence[Executor], names: Sequence[str]) -> None:
    """Spin each executor in a thread of its own until Ctrl-C or shutdown.

    One executor per thruster because rclpy rebuilds the wait set from every entity of an
    executor's nodes on each wake (with one executor for four thrusters, most of the
    container's CPU: ``docs/development.md``). The caller shuts the executors down.

    Raises
    ------
    KeyboardInterrupt
        On Ctrl-C.
    RuntimeError
        When a callback raised: the whole container stops, as with a single executor.
    """
    errors: list[tuple[str, BaseException]] = []

    def spin(name: str, executor: Executor) -> None:
        try:
            executor.spin()
        except ExternalShutdownException:
            pass
        except BaseException as exc:
            errors.append((name, exc))
            executor.context.try_shutdown()  # wakes every executor of the context: all end

    threads = [
        threading.Thread(target=spin, args=(name, executor), name=f"spin-{name}")
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
