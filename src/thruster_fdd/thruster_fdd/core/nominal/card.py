"""The model card of an exported nominal model (docs/contracts.md, "Exported model")."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from thruster_fdd.core.artifact import FORMAT_VERSION, load_card_json
from thruster_fdd.core.nominal.spec import INPUTS, MODES, NARX_ARCHITECTURES, OUTPUTS

KIND = "nominal"
"""``NominalCard.kind`` of a nominal model."""


@dataclass(frozen=True)
class NominalCard:
    """The ``model_card.json`` of an exported model (DESIGN.md "Exported model").

    Attributes
    ----------
    kind : str
        ``"nominal"``.
    inputs, outputs : tuple of str
        ``("command", "voltage")`` and ``("rpm", "current")``, in network order.
    scaling : dict
        ``{signal: {"median": float, "iqr": float}}`` in each signal's unit (IQR floored by
        ``MIN_SCALE``); the exported program holds the same constants.
    sample_time_s : float
        Sample time the model was trained at, s.
    lookbacks : dict
        ``{"input": int, "output": int}``: past samples of inputs and outputs in the regressor.
    class_names : tuple of str
        Empty for a nominal model.
    training_data_digest : str
        SHA-256 over the training samples (t, command, voltage, rpm, current).
    training_metrics : dict
        Metrics measured at training (r2 / RMSE per output, train and validation).
    code_version : str
        ``thruster_fdd`` version (and git commit when known) that trained the model.
    created : str
        ISO-8601 UTC time of export.
    model_id : str
        ``nominal-<architecture>-<hash of weights>``.
    mode : str
        ``"series-parallel"`` or ``"parallel"``: how the node runs the NARX for residuals.
    architecture : str
        ``"narx"`` or ``"narx_deadband"``.
    hidden : tuple of int
        Hidden layer sizes (tanh).
    feedback : tuple of str
        Outputs whose past values enter the regressor (``ModelSpec.feedback``).
    format_version : int
        Version of this directory layout.
    """

    kind: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    scaling: dict[str, dict[str, float]]
    sample_time_s: float
    lookbacks: dict[str, int]
    class_names: tuple[str, ...]
    training_data_digest: str
    training_metrics: dict[str, Any]
    code_version: str
    created: str
    model_id: str
    mode: str
    architecture: str
    hidden: tuple[int, ...]
    feedback: tuple[str, ...]
    format_version: int = FORMAT_VERSION
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        """The card as pretty JSON text."""
        return json.dumps(asdict(self), indent=2, sort_keys=False) + "\n"


_CARD_TYPES: dict[str, type | tuple[type, ...]] = {
    "kind": str,
    "inputs": list,
    "outputs": list,
    "scaling": dict,
    "sample_time_s": (int, float),
    "lookbacks": dict,
    "class_names": list,
    "training_data_digest": str,
    "training_metrics": dict,
    "code_version": str,
    "created": str,
    "model_id": str,
    "mode": str,
    "architecture": str,
    "hidden": list,
    "feedback": list,
    "format_version": int,
}


def read_nominal_card(model_dir: str | Path) -> NominalCard:
    """Read and validate ``model_dir/model_card.json``.

    Raises
    ------
    ValueError
        Naming the file and what is wrong: missing, not JSON, a missing or mistyped field.
    """
    path, raw = load_card_json(model_dir, _CARD_TYPES)
    unknown = sorted(set(raw) - set(_CARD_TYPES) - {"extra"})
    if unknown:
        raise ValueError(f"{path}: unknown field(s) {', '.join(unknown)}")
    lookbacks = raw["lookbacks"]
    if set(lookbacks) != {"input", "output"} or not all(
        isinstance(v, int) and v >= 0 for v in lookbacks.values()
    ):
        raise ValueError(
            f"{path}: lookbacks must be {{'input': int, 'output': int}}, got {lookbacks}"
        )
    return NominalCard(
        kind=raw["kind"],
        inputs=tuple(raw["inputs"]),
        outputs=tuple(raw["outputs"]),
        scaling=raw["scaling"],
        sample_time_s=float(raw["sample_time_s"]),
        lookbacks=dict(lookbacks),
        class_names=tuple(raw["class_names"]),
        training_data_digest=raw["training_data_digest"],
        training_metrics=raw["training_metrics"],
        code_version=raw["code_version"],
        created=raw["created"],
        model_id=raw["model_id"],
        mode=raw["mode"],
        architecture=raw["architecture"],
        hidden=tuple(int(h) for h in raw["hidden"]),
        feedback=tuple(raw["feedback"]),
        format_version=raw["format_version"],
        extra=dict(raw.get("extra", {})),
    )


def check_nominal_card(card: NominalCard, path: Path) -> None:
    """ValueError naming ``path`` and what differs from a nominal NARX card."""
    expected = {"kind": KIND, "inputs": INPUTS, "outputs": OUTPUTS, "class_names": ()}
    for key, want in expected.items():
        got = getattr(card, key)
        if got != want:
            raise ValueError(f"{path}: {key} is {got!r}, expected {want!r}")
    if card.format_version != FORMAT_VERSION:
        raise ValueError(
            f"{path}: format_version is {card.format_version}, expected {FORMAT_VERSION}"
        )
    if card.mode not in MODES:
        raise ValueError(f"{path}: mode is {card.mode!r}, expected one of {', '.join(MODES)}")
    if card.architecture not in NARX_ARCHITECTURES:
        raise ValueError(
            f"{path}: architecture is {card.architecture!r}, expected one of "
            f"{', '.join(NARX_ARCHITECTURES)}"
        )
    if not (math.isfinite(card.sample_time_s) and card.sample_time_s > 0):
        raise ValueError(f"{path}: sample_time_s must be > 0, got {card.sample_time_s}")
    if card.lookbacks["input"] < 1 or card.lookbacks["output"] < 1:
        raise ValueError(f"{path}: a NARX needs input and output lookbacks >= 1")
