"""Export of a trained NARX: weights, ``torch.export`` program and model card, written as one
folder that replaces the old one only once it has been checked.

The program takes raw past inputs and outputs and returns raw predictions (the scaler is inside
the graph); the weights file holds the same tensors as float64 arrays, which is what the runtime
(``nominal.runtime``) evaluates without torch. Before the folder is swapped in, the numpy path
must reproduce the program on probe inputs and the folder must load as the runtime loads it.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch

from thruster_fdd.core.artifact import (
    CARD_FILE,
    PROGRAM_FILE,
    WEIGHTS_FILE,
    code_version,
    file_sha256,
    read_card,
    weights_bytes,
)
from thruster_fdd.core.atomic import replaced_dir
from thruster_fdd.core.errors import ModelMismatchError
from thruster_fdd.core.nominal.card import KIND, NominalCard
from thruster_fdd.core.nominal.runtime import NarxWeights, NominalModel
from thruster_fdd.core.nominal.spec import INPUTS, MODES, OUTPUTS, IqrScaler
from thruster_fdd_shore.core.nominal.networks import LagNet

PROBE_TOLERANCE = 1e-3
"""Largest relative difference (of the output scale) allowed between the numpy path and the
exported program on probe inputs (the program runs in float32)."""


def state_arrays(module: torch.nn.Module | dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """A module's (or a state dict's) tensors as float64 numpy arrays, by name."""
    state = module.state_dict() if isinstance(module, torch.nn.Module) else module
    return {k: v.detach().to(torch.float64).numpy().copy() for k, v in state.items()}


def export_narx(
    net: LagNet,
    out_dir: str | Path,
    *,
    mode: str,
    sample_time_s: float,
    training_data_digest: str,
    training_metrics: dict[str, Any],
    extra: dict[str, Any] | None = None,
) -> NominalCard:
    """Export a trained NARX to ``out_dir`` (card, weights, program), atomically.

    Parameters
    ----------
    net : LagNet
        A trained ``narx`` or ``narx_deadband`` network.
    out_dir : str or Path
        Folder to write; an existing one is replaced only when the new one is complete and
        checked, and is left as it was on any failure.
    mode : str
        Configuration the node uses for residuals (``MODES``).
    sample_time_s : float
        Sample time of the training data, s.
    training_data_digest : str
        ``artifact.data_digest`` of the training samples.
    training_metrics : dict
        Metrics to record in the card.
    extra : dict or None
        Further JSON-able facts for the card (training options, training files).

    Returns
    -------
    NominalCard
        The card written.

    Raises
    ------
    ModelMismatchError
        If the exported folder does not reproduce the network (nothing is replaced).
    FileExistsError
        If ``out_dir`` is an existing file.
    """
    spec = net.spec
    if not spec.is_narx:
        raise ValueError(f"only NARX models are exported, got {spec.architecture}")
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    net = net.eval()
    u_ex = torch.zeros(2, spec.input_lags, 2)
    y_ex = torch.zeros(2, spec.output_lags, 2)
    batch = torch.export.Dim("batch", min=1, max=1 << 20)
    program = torch.export.export(
        net, (u_ex, y_ex), dynamic_shapes={"u_hist": {0: batch}, "y_hist": {0: batch}}
    )
    arrays = state_arrays(program.state_dict)
    weights = NarxWeights.from_arrays(arrays, spec)
    u_scaler = IqrScaler(INPUTS, *_pair(net.u_center, net.u_scale))
    y_scaler = IqrScaler(OUTPUTS, *_pair(net.y_center, net.y_scale))
    with replaced_dir(out_dir) as stage:
        torch.export.save(program, stage / PROGRAM_FILE)
        (stage / WEIGHTS_FILE).write_bytes(weights_bytes(arrays))
        card = NominalCard(
            kind=KIND,
            model_id=f"nominal-{spec.architecture}-{weights.digest()[:12]}",
            inputs=INPUTS,
            outputs=OUTPUTS,
            class_names=(),
            scaling={**u_scaler.to_dict(), **y_scaler.to_dict()},
            sample_time_s=float(sample_time_s),
            lookbacks={"input": spec.input_lags, "output": spec.output_lags},
            architecture=spec.architecture,
            hidden=spec.hidden,
            training_data_digest=training_data_digest,
            training_metrics=training_metrics,
            code_version=code_version(),
            created=datetime.now(UTC).isoformat(timespec="seconds"),
            files={name: file_sha256(stage / name) for name in (WEIGHTS_FILE, PROGRAM_FILE)},
            mode=mode,
            feedback=spec.feedback,
            extra=dict(extra or {}),
        )
        (stage / CARD_FILE).write_text(card.to_json())
        check_program(load_program(stage), NominalModel.load(stage).weights, stage / PROGRAM_FILE)
    return card


def load_program(model_dir: str | Path) -> Any:
    """The ``torch.export`` program of an exported folder, after its digest check (a program
    file is unpickled by torch, so one that differs from the card's record is never opened).

    Raises
    ------
    ModelMismatchError
        If the card is not a nominal card, the program is not listed, missing, changed or not
        loadable.
    """
    model_dir = Path(model_dir)
    card = read_card(model_dir, NominalCard, KIND)
    path = model_dir / PROGRAM_FILE
    if PROGRAM_FILE not in card.files:
        raise ModelMismatchError(f"{model_dir / CARD_FILE}: lists no {PROGRAM_FILE}")
    if not path.is_file():
        raise ModelMismatchError(f"{path}: exported program missing")
    if file_sha256(path) != card.files[PROGRAM_FILE]:
        raise ModelMismatchError(f"{path}: SHA-256 differs from the one {CARD_FILE} records")
    try:
        return torch.export.load(path)
    except Exception as exc:
        raise ModelMismatchError(f"{path}: not a loadable torch export program ({exc})") from exc


def check_program(program: Any, weights: NarxWeights, path: Path) -> None:
    """ModelMismatchError if ``weights`` (the runtime's numpy path) do not reproduce
    ``program`` on probe inputs."""
    rng = np.random.default_rng(0)
    spec = weights.spec
    u = weights.u_center + weights.u_scale * rng.normal(size=(8, spec.input_lags, 2))
    y = weights.y_center + weights.y_scale * rng.normal(size=(8, spec.output_lags, 2))
    try:
        with torch.inference_mode():
            ref = (
                program.module()(
                    torch.tensor(u, dtype=torch.float32), torch.tensor(y, dtype=torch.float32)
                )
                .double()
                .numpy()
            )
    except Exception as exc:
        raise ModelMismatchError(
            f"{path}: the program fails on (B, {spec.input_lags}, 2), (B, {spec.output_lags}, 2) "
            f"inputs ({exc})"
        ) from exc
    fast = weights.predict(u, y)
    err = np.max(np.abs(fast - ref) / weights.y_scale)
    if not err <= PROBE_TOLERANCE:
        raise ModelMismatchError(
            f"{path}: the program's graph differs from a {spec.architecture} with these weights "
            f"(max scaled difference {err:.3g})"
        )


def _pair(center: torch.Tensor, scale: torch.Tensor) -> tuple[tuple[float, ...], ...]:
    return tuple(float(v) for v in center), tuple(float(v) for v in scale)
