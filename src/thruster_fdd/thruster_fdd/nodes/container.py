"""Container: several nodes of one kind, one per thruster, in a single process.

``thruster-fdd up`` runs each model stage (``nominal_model``, ``classifier``) of all thrusters
in one container, so torch and the model code are loaded once, not once per thruster — the ROS
composition idea with plain rclpy. Every node keeps its own namespace ``/thruster/<id>``, its
parameters and its parameter services (``thruster-fdd reload`` works the same).

Usage: ``python -m thruster_fdd.nodes.container KIND --thrusters t0 t1 [-p name=value ...]``
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
    """Parse a ``-p`` value the way ROS parameter overrides read numbers."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            continue
    return text


def main(argv: list[str] | None = None) -> None:
    """Create one node of ``KIND`` per thruster and spin them all until Ctrl-C."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("kind", choices=sorted(KINDS))
    parser.add_argument("--thrusters", nargs="+", required=True, metavar="ID")
    parser.add_argument("-p", dest="params", action="append", default=[], metavar="NAME=VALUE")
    args = parser.parse_args(argv)
    module, cls_name = KINDS[args.kind]
    node_cls = getattr(importlib.import_module(f"thruster_fdd.nodes.{module}"), cls_name)
    shared = [Parameter(k, value=_value(v)) for k, _, v in (p.partition("=") for p in args.params)]
    stop_with_parent()
    rclpy.init()
    executor = SingleThreadedExecutor()
    nodes = []
    try:
        for tid in args.thrusters:
            overrides = [Parameter("thruster_id", value=tid), *shared]
            node = node_cls(namespace=f"/thruster/{tid}", parameter_overrides=overrides)
            nodes.append(node)
            executor.add_node(node)
        executor.spin()
    except ValueError as exc:
        print(f"container {args.kind}: cannot start: {exc}", file=sys.stderr)
        sys.exit(1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        release_and_destroy(executor, nodes)
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
