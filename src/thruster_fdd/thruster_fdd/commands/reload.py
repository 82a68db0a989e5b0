"""``thruster-fdd reload``: load newly exported models into running nodes, without a restart.

Sets the ``model_dir`` parameter of each thruster's ``nominal_model`` and/or ``classifier``
node through its parameter service. A node checks the new model first and refuses one that
does not fit (the reason is printed); it then keeps running its old model.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from thruster_fdd.commands.common import EXIT_FAILED, EXIT_OK
from thruster_fdd.core.errors import BadInputError

NAME = "reload"
HELP = "load newly exported models into running nodes without a restart"
DESCRIPTION = (
    "Point the running model nodes of the given thrusters at newly exported models. Each node "
    "checks the model card before switching; a refused model leaves the old one running and "
    "is reported with its reason (exit 1)."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd reload``."""
    p.add_argument("--thrusters", nargs="+", required=True, metavar="ID", help="e.g. t0 t1")
    p.add_argument("--nominal", type=Path, metavar="DIR", help="new nominal model folder")
    p.add_argument("--classifier", type=Path, metavar="DIR", help="new classifier folder")
    p.add_argument("--timeout", type=float, default=10.0, help="per node, s")


def run(args: argparse.Namespace) -> int:
    """Set ``model_dir`` on every named node; returns the exit code."""
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    targets = [("nominal_model", args.nominal), ("classifier", args.classifier)]
    targets = [(node, folder) for node, folder in targets if folder is not None]
    if not targets:
        raise BadInputError("give --nominal DIR and/or --classifier DIR")
    for _, folder in targets:
        if not folder.is_dir():
            raise BadInputError(f"{folder}: no such model folder")
    rclpy.init()
    node = rclpy.create_node("thruster_fdd_reload")
    failures = 0
    try:
        for tid in args.thrusters:
            for node_name, folder in targets:
                remote = f"/thruster/{tid}/{node_name}"
                client = AsyncParameterClient(node, remote)
                if not client.wait_for_services(timeout_sec=args.timeout):
                    print(f"{remote}: not running", file=sys.stderr)
                    failures += 1
                    continue
                future = client.set_parameters(
                    [Parameter("model_dir", Parameter.Type.STRING, str(folder.resolve()))]
                )
                rclpy.spin_until_future_complete(node, future, timeout_sec=args.timeout)
                result = future.result()
                if result is None:
                    print(f"{remote}: no answer within {args.timeout:g} s", file=sys.stderr)
                    failures += 1
                elif not result.results[0].successful:
                    print(f"{remote}: refused: {result.results[0].reason}", file=sys.stderr)
                    failures += 1
                else:
                    print(f"{remote}: now running {folder}")
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return EXIT_FAILED if failures else EXIT_OK
