"""Where the workspace keeps its exported models."""

from __future__ import annotations

import os
from pathlib import Path

MODELS_ENV = "THRUSTER_FDD_MODELS"


def default_models_dir() -> Path:
    """The models folder: ``$THRUSTER_FDD_MODELS``, else ``models/`` of the source workspace.

    The workspace root is found by walking up from this file to the folder that holds
    ``thruster_fdd_msgs/`` (colcon's symlink install keeps the sources' location); outside a
    workspace it is ``./models``.
    """
    env = os.environ.get(MODELS_ENV)
    if env:
        return Path(env)
    for parent in Path(__file__).resolve().parents:
        if (parent / "thruster_fdd_msgs").is_dir() and (parent / "models").is_dir():
            return parent / "models"
    return Path("models")
