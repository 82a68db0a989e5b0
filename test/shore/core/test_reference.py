"""Reference load curves: computed ashore, exported, read on the vehicle by digest."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from thruster_fdd.core.artifact import CARD_FILE, WEIGHTS_FILE, default_models_dir
from thruster_fdd.core.diagnosis.reference import ThrustReference
from thruster_fdd.core.errors import BadInputError, ModelMismatchError
from thruster_fdd_shore.cli import main
from thruster_fdd_shore.core.reference import (
    config_digest,
    export_reference,
    reference_arrays,
    voltage_grid,
)
from thruster_fdd_shore.core.sim.config import load_config

T100 = load_config("t100")


def test_the_shipped_reference_is_the_t100_physics_of_today() -> None:
    folder = default_models_dir() / "reference"
    card = json.loads((folder / CARD_FILE).read_text())
    assert card["extra"]["config_digest"] == config_digest(T100)
    shipped = ThrustReference.load(folder)
    fresh = reference_arrays(T100, (15.0,))
    b = shipped.voltage_bin(15.0)
    for family in ("blades", "fouling"):
        for reverse in (False, True):
            curves = shipped.curves(family, 15.0, reverse)
            f, d = ("blades", "fouling").index(family), int(reverse)
            np.testing.assert_allclose(curves.power, fresh["power"][0, f, d], rtol=1e-9)
            np.testing.assert_allclose(curves.thrust, fresh["thrust"][0, f, d], rtol=1e-9)
    assert shipped.voltages[b] == 15.0


def test_an_exported_reference_loads_and_a_changed_one_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "ref"
    card = export_reference(T100, "t100", out, voltage_grid(14.5, 15.0))
    assert card.model_id.startswith("reference-t100-")
    reference = ThrustReference.load(out)
    assert list(reference.voltages) == [14.5, 15.0]
    healthy = reference.curves("blades", 15.0, False)
    broken = reference.curves("blades", 15.0, False).power_at(300.0)
    assert broken.shape == (len(reference.severities),)
    # Blades lost lighten the load at a given speed.
    assert healthy.power_at(300.0)[0] > healthy.power_at(300.0)[-1]
    weights = out / WEIGHTS_FILE
    weights.write_bytes(weights.read_bytes()[:-8] + b"\0" * 8)
    with pytest.raises(ModelMismatchError, match="SHA-256"):
        ThrustReference.load(out)


def test_arrays_of_the_wrong_shape_are_refused() -> None:
    arrays = reference_arrays(T100, (15.0,))
    arrays["power"] = arrays["power"][..., :-1]
    with pytest.raises(ModelMismatchError, match="power"):
        ThrustReference(arrays)
    arrays = reference_arrays(T100, (15.0,))
    arrays["thrust"] = np.full_like(arrays["thrust"], np.nan)
    with pytest.raises(ModelMismatchError, match="thrust"):
        ThrustReference(arrays)


def test_voltage_ranges_outside_the_physics_are_bad_input() -> None:
    assert list(voltage_grid(10.0, 11.0)) == [10.0, 10.5, 11.0]
    for low, high in ((5.0, 10.0), (12.0, 11.0), (10.0, float("nan")), (10.0, 31.0)):
        with pytest.raises(BadInputError, match="voltage range"):
            voltage_grid(low, high)


def test_the_command_refuses_to_replace_without_force(tmp_path: Path, capsys) -> None:
    out = tmp_path / "ref"
    args = ["reference", "--out", str(out), "--min-voltage", "15", "--max-voltage", "15"]
    assert main(args) == 0
    assert "reference-t100-" in capsys.readouterr().out
    assert main(args) == 2
    assert "--force" in capsys.readouterr().err
    assert main([*args, "--force"]) == 0
