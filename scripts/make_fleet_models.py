#!/usr/bin/env python3
"""Write a models folder that differs from another in the classifier's unknown-probability
threshold only (a different pair for ``fleet compare``): ``nominal/``, ``classifier/`` and
``reference/`` copied, ``unknown.probability_threshold`` of the classifier card replaced.

    python scripts/make_fleet_models.py /tmp/strict-models --probability-threshold 0.999
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from thruster_fdd.core.artifact import CARD_FILE, default_models_dir


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path, help="models folder to write (must not exist)")
    p.add_argument("--models", type=Path, default=default_models_dir(), help="folder to copy")
    p.add_argument("--probability-threshold", type=float, default=0.999, help="0..1")
    args = p.parse_args(argv)
    for part in ("nominal", "classifier", "reference"):
        shutil.copytree(args.models / part, args.out / part)
    card_path = args.out / "classifier" / CARD_FILE
    card = json.loads(card_path.read_text())
    card["unknown"]["probability_threshold"] = args.probability_threshold
    card_path.write_text(json.dumps(card, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
