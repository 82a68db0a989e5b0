"""``thruster-fdd record``: the recorder node in the foreground."""

from __future__ import annotations

import argparse
from pathlib import Path

from thruster_fdd_shore.commands.common import EXIT_OK, positive_float

NAME = "record"
HELP = "record every topic of the graph to a rosbag2 bag folder (MCAP files)"
DESCRIPTION = (
    "Run the recorder node in the foreground: every discovered topic, as raw CDR, into "
    "a rosbag2 bag folder --out/<start time>/ (metadata.yaml and size/duration-split MCAP "
    "files; <start time>_2/ ... when that folder exists) until Ctrl-C. More settings: the "
    "recorder's ROS parameters (README)."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``thruster-fdd record``."""
    p.add_argument(
        "--out",
        type=Path,
        default=Path("recordings"),
        metavar="DIR",
        help="folder the bag folder is made in (default: %(default)s)",
    )
    p.add_argument("--max-file-mb", type=positive_float, default=256.0, help="split size, MiB")
    p.add_argument(
        "--compression",
        choices=("zstd", "lz4", "none"),
        default="zstd",
        help="MCAP chunk compression (default: %(default)s)",
    )
    p.add_argument("--vehicle", default="sim-auv", help="vehicle name for the metadata")


def run(args: argparse.Namespace) -> int:
    """Run the recorder until Ctrl-C."""
    from thruster_fdd.nodes import recorder

    params = {
        "output_dir": args.out,
        "max_file_mb": args.max_file_mb,
        "compression": args.compression,
        "vehicle": args.vehicle,
    }
    recorder.main(["--ros-args", *(a for k, v in params.items() for a in ("-p", f"{k}:={v}"))])
    return EXIT_OK
