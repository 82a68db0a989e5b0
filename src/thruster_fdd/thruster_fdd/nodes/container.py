"""Container: nodes of one or more kinds, one of each per thruster, in a single process.

``thruster-fdd up`` runs both model stages (``nominal_model``, ``classifier``) of all thrusters
in one container, so torch and the model code are loaded once, not once per thruster and stage
(about 300 MB each), and each thruster's classifier gets its residuals straight from its
nominal model in the process (intra-process delivery, ``--no-intra-process`` turns it off) —
the ROS composition idea with plain rclpy. Every node keeps its own namespace ``/thruster/<id>``,
its parameters and its parameter services (``thruster-fdd reload`` works the same).

Usage: ``python -m thruster_fdd.nodes.container KIND [KIND ...] --thrusters t0 t1
[-p [KIND:]name=value ...]``; a ``KIND:`` prefix gives the parameter to that kind's nodes only.
"""

from __future__ import annotations

import argparse
import importlib
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
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
    executor = SingleThreadedExecutor()
    nodes = []
    try:
        for tid in args.thrusters:
            made = {}
            for kind, node_cls in classes.items():
                overrides = [Parameter("thruster_id", value=tid), *params[kind]]
                made[kind] = node_cls(namespace=f"/thruster/{tid}", parameter_overrides=overrides)
                nodes.append(made[kind])
                executor.add_node(made[kind])
            if args.intra_process and {"nominal_model", "classifier"} <= made.keys():
                made["classifier"].take_residuals_from(made["nominal_model"])
        executor.spin()
    except ValueError as exc:
        print(f"container {' '.join(args.kinds)}: cannot start: {exc}", file=sys.stderr)
        sys.exit(1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        release_and_destroy(executor, nodes)
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
