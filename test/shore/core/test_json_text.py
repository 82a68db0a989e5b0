"""``core.json_text``: strict JSON text of result data whose numbers may not be finite."""

from __future__ import annotations

import json

import numpy as np
import pytest

from thruster_fdd_shore.core.json_text import json_text


def test_non_finite_numbers_become_what_the_contract_says_at_any_depth() -> None:
    """Equality with the expected data also says no Infinity or NaN was written (they would
    load as floats)."""
    data = {"a": [1.0, float("inf"), (np.float64(float("nan")), 2)], "b": {"c": -np.inf}}
    text = json_text(data, nonfinite=lambda _x: None, indent=2)
    assert text.endswith("\n")
    assert json.loads(text) == {
        "a": [1.0, None, [None, 2]],
        "b": {"c": None},
    }
    text = json_text(data, nonfinite=str, indent=1)
    assert json.loads(text) == {
        "a": [1.0, "inf", ["nan", 2]],
        "b": {"c": "-inf"},
    }


def test_numpy_scalars_are_written_as_numbers() -> None:
    data = {"n": np.int64(3), "x": np.float32(0.5), "ok": np.bool_(True)}
    assert json.loads(json_text(data, nonfinite=str, indent=2)) == {"n": 3, "x": 0.5, "ok": True}


def test_a_type_json_lacks_is_a_bug() -> None:
    with pytest.raises(TypeError):
        json_text({"s": {1, 2}}, nonfinite=str, indent=2)
