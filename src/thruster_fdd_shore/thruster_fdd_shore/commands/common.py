"""What the subcommands share: exit codes and argument types."""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from thruster_fdd.core.errors import BadInputError

EXIT_OK = 0
"""Success."""

EXIT_FAILED = 1
"""The command ran but its check failed (``replay``, ``reload``, ``diagnose --expect``)."""

EXIT_BAD_INPUT = 2
"""Bad input: one line on stderr names the input and what is wrong."""


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0 (seeds, counts)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def finite_float(text: str) -> float:
    """argparse type: a finite number (times, offsets)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


MODELS_HELP = "default: $THRUSTER_FDD_MODELS, else the workspace's models/"
"""How every command's default models folder is found (``default_models_dir``)."""


def model_folder(given: Path | None, stage: str) -> Path:
    """``given``, else ``<default models folder>/<stage>`` (``nominal``, ``classifier``): the one
    rule of every command, whatever the current folder."""
    from thruster_fdd.core.artifact import default_models_dir

    return given if given is not None else default_models_dir() / stage


def refuse_shipped(out: Path, force: bool) -> None:
    """Refuse to replace an exported model of the models folder (``default_models_dir``: the
    committed models, or ``$THRUSTER_FDD_MODELS``) unless ``force``.

    Raises
    ------
    BadInputError
        If ``out`` is one of that folder's model folders and holds a model card.
    """
    from thruster_fdd.core.artifact import CARD_FILE, default_models_dir

    shipped = default_models_dir().resolve()
    if force or not (out / CARD_FILE).is_file() or out.resolve().parent != shipped:
        return
    raise BadInputError(
        f"--out {out}: the model {shipped.name}/{out.name} that the nodes, up and replay use "
        "would be replaced; give another --out, or --force"
    )


def check_output(path: Path, option: str, *, folder: bool = False) -> None:
    """Refuse an output path that cannot be written, before any work is done.

    Parameters
    ----------
    path : Path
        The file (or, with ``folder``, the folder) a command will write.
    option : str
        The option that named it, for the message (``--out``).
    folder : bool
        Whether ``path`` is a folder.

    Raises
    ------
    BadInputError
        If ``path`` exists as the other kind (a folder for a file, a file for a folder), or its
        nearest existing parent is not a writable folder.
    """
    if path.exists() and path.is_dir() != folder:
        kind = "a folder" if path.is_dir() else "a file"
        raise BadInputError(f"{option} {path}: exists and is {kind}")
    parent = path.parent.absolute()
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise BadInputError(f"{option} {path}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BadInputError(f"{option} {path}: cannot write in {parent}")


def check_models(models: Path) -> None:
    """Refuse a models folder whose exported models a node would refuse at start.

    Loads ``models/nominal`` and, when it holds a card, ``models/classifier`` as their nodes
    do: the vehicle's loaders (every card field and range, the SHA-256 of every file, the
    weights against the card) and the classifier's stream with the node's default parameters
    (``up`` sets no other), and checks that the classifier was made with this nominal model at
    its sample time. A node started on them would exit 1 with the same reason; this says it
    before anything starts, naming the file (exit 2).

    Raises
    ------
    ModelMismatchError
        Naming the file and what is wrong.
    """
    from thruster_fdd.core.artifact import CARD_FILE
    from thruster_fdd.core.diagnosis.model import ClassifierModel
    from thruster_fdd.core.diagnosis.stream import DiagnosisStream
    from thruster_fdd.core.errors import ModelMismatchError
    from thruster_fdd.core.nominal.runtime import NominalModel
    from thruster_fdd.nodes import classifier as classifier_node
    from thruster_fdd_shore.core.diagnosis.offline import check_pair

    nominal = NominalModel.load(models / "nominal")
    if not (models / "classifier" / CARD_FILE).is_file():
        return
    classifier = ClassifierModel.load(models / "classifier")
    defaults = {name: default for name, default, _ in classifier_node.PARAMETERS}
    try:
        DiagnosisStream(classifier, **classifier_node.stream_options(defaults.__getitem__))
    except ValueError as exc:
        raise ModelMismatchError(f"{models / 'classifier' / CARD_FILE}: {exc}") from None
    check_pair(nominal, classifier, models / "classifier")
