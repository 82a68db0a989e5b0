"""Reference load curves of a thruster type, computed from its simulator configuration and
exported for the vehicle's health node (``thruster_fdd.core.diagnosis.reference``).

For each supply-voltage bin and each fault family (blades lost 0..2, fouling 0..2) the
configuration is solved at steady state on a grid of severities and commands
(``sim.steady.steady_curves``): speed, electrical power ``(V - R I) I`` and thrust. The power is
tabulated against speed (the load a propeller puts on its motor at a given speed does not
depend on the command path), the thrust against command magnitude.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from thruster_fdd.core.artifact import (
    CARD_FILE,
    WEIGHTS_FILE,
    code_version,
    file_sha256,
    weights_bytes,
)
from thruster_fdd.core.atomic import replaced_dir
from thruster_fdd.core.diagnosis.reference import (
    FAULT_FAMILIES,
    MAX_SEVERITY,
    MIN_SPEED_FRACTION,
    REFERENCE_KIND,
    SEVERITY_STEP,
    VOLTAGE_STEP_V,
    ReferenceCard,
    ThrustReference,
)
from thruster_fdd.core.errors import BadInputError
from thruster_fdd_shore.core.sim.config import SimConfig, config_to_dict
from thruster_fdd_shore.core.sim.plant import RAD_S_TO_RPM, severity_spec
from thruster_fdd_shore.core.sim.steady import steady_curves

DEFAULT_VOLTAGES_V: tuple[float, float] = (10.0, 20.0)
"""Supply range of an exported reference, V (a 3S to 5S battery; outside it the nearest bin's
curves are used)."""

COMMAND_POINTS = 51
"""Command magnitudes of the thrust tables, uniform on 0..1."""

SPEED_POINTS = 160
"""Speed points of the power-at-speed tables."""


def config_digest(config: SimConfig) -> str:
    """SHA-256 (hex) of a configuration's canonical JSON."""
    text = json.dumps(config_to_dict(config), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def voltage_grid(low_v: float, high_v: float) -> np.ndarray:
    """Bins from ``low_v`` to ``high_v`` V at ``VOLTAGE_STEP_V``, shape (B,).

    Raises
    ------
    BadInputError
        If the range is not finite, inverted or outside 6..30 V.
    """
    if not (np.isfinite(low_v) and np.isfinite(high_v) and 6.0 <= low_v <= high_v <= 30.0):
        raise BadInputError(f"voltage range must lie within 6..30 V, got {low_v}..{high_v}")
    n = round((high_v - low_v) / VOLTAGE_STEP_V) + 1
    return np.round(low_v + VOLTAGE_STEP_V * np.arange(n), 6)


def _bin_arrays(config: SimConfig, voltage: float, severities: np.ndarray) -> dict:
    """Every family and direction at ``voltage`` V, in one steady-state solve."""
    magnitudes = np.linspace(0.0, 1.0, COMMAND_POINTS)
    specs = [severity_spec(f, float(s), voltage) for f in FAULT_FAMILIES for s in severities]
    commands = np.concatenate([magnitudes, -magnitudes])
    rpm, current, plants = steady_curves(config, commands, voltage, specs)
    k, n = len(severities), COMMAND_POINTS
    shape = (len(FAULT_FAMILIES), 2)
    thrust = np.empty((*shape, k, n))
    speeds = np.empty((*shape, SPEED_POINTS))
    power = np.empty((*shape, k, SPEED_POINTS))
    informative = np.empty(shape)
    for i in range(len(FAULT_FAMILIES)):
        rows = slice(i * k, (i + 1) * k)
        fam = plants[rows]
        r_int = np.array([p.r_int for p in fam])
        for d, reverse in enumerate((False, True)):
            cols = slice(n, 2 * n) if reverse else slice(0, n)
            w = np.abs(rpm[rows, cols]) / RAD_S_TO_RPM
            ibus = current[rows, cols]
            k_t = np.array([p.k_thrust_rev if reverse else p.k_thrust for p in fam])
            watts = (voltage - r_int[:, None] * ibus) * ibus
            grid = np.linspace(0.0, float(w.max()), SPEED_POINTS)
            for j in range(k):
                moving = w[j] > 0.0
                if moving.sum() < 2:
                    power[i, d, j] = watts[j, -1]
                else:
                    power[i, d, j] = np.interp(grid, w[j, moving], watts[j, moving])
            thrust[i, d] = k_t[:, None] * w * w
            speeds[i, d] = grid
            informative[i, d] = MIN_SPEED_FRACTION * float(w[0].max())
    return {"thrust": thrust, "speeds": speeds, "power": power, "informative_speed": informative}


def reference_arrays(
    config: SimConfig,
    voltages: Sequence[float],
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, np.ndarray]:
    """The arrays of a reference folder (``thruster_fdd.core.diagnosis.reference``).

    Parameters
    ----------
    config : SimConfig
        The thruster type (spread not applied).
    voltages : sequence of float, length B
        Supply-voltage bins, V, uniform at ``VOLTAGE_STEP_V``.
    progress : callable or None
        Called with ``(bins done, B)`` after each bin (about 1.3 s a bin for ``t100``).
    """
    severities = np.round(np.arange(0.0, MAX_SEVERITY + 1e-9, SEVERITY_STEP), 10)
    bins = []
    for i, v in enumerate(voltages):
        bins.append(_bin_arrays(config, float(v), severities))
        if progress is not None:
            progress(i + 1, len(voltages))
    out = {k: np.stack([b[k] for b in bins]) for k in bins[0]}
    out["voltages"] = np.asarray(voltages, dtype=float)
    out["severities"] = severities
    out["commands"] = np.linspace(0.0, 1.0, COMMAND_POINTS)
    return out


def reference_for(config: SimConfig, voltages: Sequence[float] = (15.0,)) -> ThrustReference:
    """An in-memory reference of ``config`` on the given bins (tests, studies, offline tools)."""
    return ThrustReference(reference_arrays(config, voltages), name="in-memory reference")


def export_reference(
    config: SimConfig,
    thruster_type: str,
    out_dir: str | Path,
    voltages: Sequence[float],
    progress: Callable[[int, int], None] | None = None,
) -> ReferenceCard:
    """Compute and write a reference folder (card and arrays), atomically, and check that it
    loads as the health node loads it.

    Parameters
    ----------
    config : SimConfig
        The thruster type.
    thruster_type : str
        Its name in the card (a preset name or the configuration file's name).
    out_dir : str or Path
        Folder to write; an existing one is replaced only once the new one is complete.
    voltages : sequence of float
        Supply-voltage bins, V (``voltage_grid``).
    progress : callable or None
        As for ``reference_arrays``.
    """
    arrays = reference_arrays(config, voltages, progress)
    digest = config_digest(config)
    with replaced_dir(out_dir) as stage:
        (stage / WEIGHTS_FILE).write_bytes(weights_bytes(arrays))
        card = ReferenceCard(
            kind=REFERENCE_KIND,
            model_id=f"reference-{thruster_type}-{digest[:12]}",
            inputs=("voltage", "rpm", "current", "command"),
            outputs=("effectiveness",),
            class_names=(),
            scaling={},
            sample_time_s=0.0,
            lookbacks={},
            architecture="steady_state_curves",
            hidden=(),
            training_data_digest=digest,
            training_metrics={},
            code_version=code_version(),
            created=datetime.now(UTC).isoformat(timespec="seconds"),
            files={WEIGHTS_FILE: file_sha256(stage / WEIGHTS_FILE)},
            extra={
                "thruster_type": thruster_type,
                "config_digest": digest,
                "voltage_range_v": [float(voltages[0]), float(voltages[-1])],
            },
        )
        (stage / CARD_FILE).write_text(card.to_json())
        ThrustReference.load(stage)
    return card


def reference_of(config: SimConfig, shipped: Path | None = None) -> ThrustReference:
    """The reference of ``config`` over ``DEFAULT_VOLTAGES_V``: the ``shipped`` folder (default:
    the models folder's ``reference/``) when it was computed from this configuration, else one
    computed now in memory (about 1.3 s a bin)."""
    from thruster_fdd.core.artifact import default_models_dir, read_card
    from thruster_fdd.core.errors import ModelMismatchError

    folder = shipped if shipped is not None else default_models_dir() / "reference"
    try:
        card = read_card(folder, ReferenceCard, REFERENCE_KIND)
        if card.extra.get("config_digest") == config_digest(config):
            return ThrustReference.load(folder)
    except ModelMismatchError:
        pass
    return ThrustReference(
        reference_arrays(config, voltage_grid(*DEFAULT_VOLTAGES_V)), name=config.name
    )
