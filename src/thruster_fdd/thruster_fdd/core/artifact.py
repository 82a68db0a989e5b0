"""Where the workspace keeps its exported models."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

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


CARD_FILE = "model_card.json"


PROGRAM_FILE = "model.pt2"


FORMAT_VERSION = 1


def load_card_json(
    model_dir: str | Path,
    card_types: dict[str, type | tuple[type, ...]],
    kind: str | None = None,
) -> tuple[Path, dict[str, Any]]:
    """Read ``model_dir/model_card.json`` and check it has every field of ``card_types``.

    Shared by the nominal and the classifier card readers, which add their own checks.

    Parameters
    ----------
    model_dir : str or Path
        Exported model folder.
    card_types : dict of str to type
        Required fields and their JSON types (bool is never accepted for a number).
    kind : str or None
        When given, the card's ``kind`` must equal it (checked before the fields).

    Returns
    -------
    (Path, dict)
        The card's path and its content.

    Raises
    ------
    ValueError
        Naming the file and what is wrong: missing, not JSON, not an object, another kind, a
        missing or mistyped field.
    """
    path = Path(model_dir) / CARD_FILE
    if not path.is_file():
        raise ValueError(f"{path}: model card missing")
    try:
        raw = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(raw).__name__}")
    if kind is not None and raw.get("kind") != kind:
        raise ValueError(f"{path}: kind is {raw.get('kind')!r}, expected {kind!r}")
    missing = [k for k in card_types if k not in raw]
    if missing:
        raise ValueError(f"{path}: missing field(s) {', '.join(missing)}")
    for key, typ in card_types.items():
        if not isinstance(raw[key], typ) or isinstance(raw[key], bool):
            raise ValueError(f"{path}: field {key!r} has type {type(raw[key]).__name__}")
    return path, raw


def data_digest(traces_arrays: list[np.ndarray]) -> str:
    """SHA-256 (hex) over float64 sample arrays, each shape (n, k), in order."""
    h = hashlib.sha256()
    for arr in traces_arrays:
        h.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
    return h.hexdigest()


def code_version() -> str:
    """``thruster_fdd <version>`` of the installed package."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"thruster_fdd {version('thruster_fdd')}"
    except PackageNotFoundError:
        return "thruster_fdd unknown"
