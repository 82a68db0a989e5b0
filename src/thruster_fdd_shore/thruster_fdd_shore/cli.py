"""The ``thruster-fdd`` command: wires the subcommands of ``thruster_fdd_shore.commands``.

Every subcommand has ``--help``; exit code 0 on success, 1 when a check it runs fails, 2 on bad
input with one line naming the input and what is wrong. Any other error is a bug and keeps its
traceback.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence
from typing import Any, TextIO

from thruster_fdd.core.errors import BadInputError, PartialInputWarning
from thruster_fdd_shore.commands import (
    diagnose,
    discrepancy,
    emulate,
    evaluate,
    fleet,
    record,
    reference,
    reload,
    replay,
    simulate,
    train,
    up,
)
from thruster_fdd_shore.commands.common import EXIT_BAD_INPUT

COMMANDS = (
    simulate,
    train,
    evaluate,
    diagnose,
    discrepancy,
    replay,
    up,
    record,
    reload,
    reference,
    emulate,
    fleet,
)
"""The subcommand modules, in the order ``--help`` lists them."""


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line with a pointer to ``--help``."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """Build the ``thruster-fdd`` argument parser with every subcommand."""
    parser = _Parser(
        prog="thruster-fdd",
        description=(
            "Onboard soft-fault detection and diagnosis for AUV thrusters (ROS 2 Jazzy). "
            "Run 'thruster-fdd SUBCOMMAND --help' for each subcommand."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="SUBCOMMAND", required=True)
    for command in COMMANDS:
        p = sub.add_parser(
            command.NAME,
            help=command.HELP,
            description=command.DESCRIPTION,
            formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        )
        command.add_arguments(p)
        p.set_defaults(run=command.run)
    return parser


def _one_line_warnings(command: str) -> None:
    """Print a ``PartialInputWarning`` as one line naming the subcommand; others as usual."""
    default = warnings.showwarning

    def show(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: TextIO | None = None,
        line: str | None = None,
    ) -> Any:
        if issubclass(category, PartialInputWarning):
            print(f"thruster-fdd {command}: warning: {message}", file=sys.stderr)
        else:
            default(message, category, filename, lineno, file, line)

    warnings.showwarning = show


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``thruster-fdd``; returns the process exit code."""
    args = build_parser().parse_args(argv)
    _one_line_warnings(args.command)
    try:
        return int(args.run(args))
    except BadInputError as exc:
        print(f"thruster-fdd {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        if exc.filename is None:
            raise
        # A path the user gave cannot be read or written: bad input, not a bug.
        print(
            f"thruster-fdd {args.command}: error: {exc.filename}: {exc.strerror}", file=sys.stderr
        )
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
