"""Export of a trained NARX: the ``torch.export`` program and its model card.

The program takes raw past inputs and outputs and returns raw predictions (the scaler is inside
the graph).
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch

from thruster_fdd.core.artifact import CARD_FILE, PROGRAM_FILE, code_version
from thruster_fdd.core.nominal.card import KIND, NominalCard
from thruster_fdd.core.nominal.networks import LagNet
from thruster_fdd.core.nominal.runtime import NarxWeights
from thruster_fdd.core.nominal.spec import INPUTS, MODES, OUTPUTS, IqrScaler


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
    """Export a trained NARX to ``out_dir`` (``model.pt2`` + ``model_card.json``).

    Parameters
    ----------
    net : LagNet
        A trained ``narx`` or ``narx_deadband`` network.
    out_dir : str or Path
        Directory to write (created; existing card/program replaced).
    mode : str
        Configuration the node uses for residuals (``MODES``).
    sample_time_s : float
        Sample time of the training data, s.
    training_data_digest : str
        ``data_digest`` of the training samples.
    training_metrics : dict
        Metrics to record in the card.
    extra : dict or None
        Further JSON-able facts for the card (training options).

    Returns
    -------
    NominalCard
        The card written.
    """
    spec = net.spec
    if not spec.is_narx:
        raise ValueError(f"only NARX models are exported, got {spec.architecture}")
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    net = net.eval()
    u_ex = torch.zeros(2, spec.input_lags, 2)
    y_ex = torch.zeros(2, spec.output_lags, 2)
    batch = torch.export.Dim("batch", min=1, max=1 << 20)
    program = torch.export.export(
        net, (u_ex, y_ex), dynamic_shapes={"u_hist": {0: batch}, "y_hist": {0: batch}}
    )
    torch.export.save(program, out / PROGRAM_FILE)
    weights = NarxWeights.from_state_dict(program.state_dict, spec)
    u_scaler = IqrScaler(INPUTS, *_pair(net.u_center, net.u_scale))
    y_scaler = IqrScaler(OUTPUTS, *_pair(net.y_center, net.y_scale))
    scaling = {**u_scaler.to_dict(), **y_scaler.to_dict()}
    card = NominalCard(
        kind=KIND,
        inputs=INPUTS,
        outputs=OUTPUTS,
        scaling=scaling,
        sample_time_s=float(sample_time_s),
        lookbacks={"input": spec.input_lags, "output": spec.output_lags},
        class_names=(),
        training_data_digest=training_data_digest,
        training_metrics=training_metrics,
        code_version=code_version(),
        created=datetime.now(UTC).isoformat(timespec="seconds"),
        model_id=f"nominal-{spec.architecture}-{weights.digest()[:12]}",
        mode=mode,
        architecture=spec.architecture,
        hidden=spec.hidden,
        feedback=spec.feedback,
        extra=dict(extra or {}),
    )
    (out / CARD_FILE).write_text(card.to_json())
    return card


def _pair(center: torch.Tensor, scale: torch.Tensor) -> tuple[tuple[float, ...], ...]:
    return tuple(float(v) for v in center), tuple(float(v) for v in scale)
