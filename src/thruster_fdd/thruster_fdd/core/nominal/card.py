"""The model card of an exported nominal model (docs/contracts.md, "Exported model")."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from thruster_fdd.core.artifact import CARD_FILE, ModelCard, read_card
from thruster_fdd.core.errors import ModelMismatchError
from thruster_fdd.core.nominal.spec import INPUTS, MODES, NARX_ARCHITECTURES, OUTPUTS

KIND = "nominal"
"""``NominalCard.kind`` of a nominal model."""


@dataclass(frozen=True, kw_only=True)
class NominalCard(ModelCard):
    """The card of an exported nominal NARX: ``ModelCard``'s fields with these meanings, plus
    ``mode`` and ``feedback``.

    Attributes
    ----------
    inputs, outputs : tuple of str
        ``("command", "voltage")`` and ``("rpm", "current")``, in network order.
    scaling : dict
        ``{signal: {"center": median, "scale": IQR}}`` of the four signals (IQR floored by
        ``spec.MIN_SCALE``); the weights hold the same constants.
    lookbacks : dict
        ``{"input": int, "output": int}``: past samples of inputs and outputs in the regressor.
    architecture : str
        ``"narx"`` or ``"narx_deadband"``.
    hidden : tuple of int
        Hidden layer sizes (tanh).
    mode : str
        ``"series-parallel"`` or ``"parallel"``: how the node runs the NARX for residuals.
    feedback : tuple of str
        Outputs whose past values enter the regressor (``ModelSpec.feedback``).
    """

    mode: str
    feedback: tuple[str, ...]


def read_nominal_card(model_dir: str | Path) -> NominalCard:
    """Read and check ``model_dir/model_card.json`` as a nominal NARX's card.

    Raises
    ------
    ModelMismatchError
        Naming the file and what is wrong or differs from a nominal NARX card.
    """
    card = read_card(model_dir, NominalCard, KIND)
    path = Path(model_dir) / CARD_FILE
    expected = {"inputs": INPUTS, "outputs": OUTPUTS, "class_names": ()}
    for key, want in expected.items():
        got = getattr(card, key)
        if got != want:
            raise ModelMismatchError(f"{path}: {key} is {got!r}, expected {want!r}")
    if card.mode not in MODES:
        raise ModelMismatchError(
            f"{path}: mode is {card.mode!r}, expected one of {', '.join(MODES)}"
        )
    if card.architecture not in NARX_ARCHITECTURES:
        raise ModelMismatchError(
            f"{path}: architecture is {card.architecture!r}, expected one of "
            f"{', '.join(NARX_ARCHITECTURES)}"
        )
    if not card.sample_time_s > 0:
        raise ModelMismatchError(f"{path}: sample_time_s must be > 0, got {card.sample_time_s}")
    if set(card.lookbacks) != {"input", "output"} or min(card.lookbacks.values()) < 1:
        raise ModelMismatchError(
            f"{path}: lookbacks must be {{'input': n, 'output': m}} with n, m >= 1, got "
            f"{card.lookbacks}"
        )
    try:
        card.scaling_of(INPUTS + OUTPUTS)
    except ModelMismatchError as exc:
        raise ModelMismatchError(f"{path}: {exc}") from None
    return card
