"""The model container's command line: parameters for all kinds or for one (no graph needed)."""

from __future__ import annotations

import pytest

from thruster_fdd.nodes.container import parse_parameters


def test_parameters_go_to_every_kind_or_to_the_named_one() -> None:
    params = parse_parameters(
        ["nominal_model", "classifier"],
        ["classifier:model_dir=/m/c", "nominal_model:model_dir=/m/n", "diagnostics_period_s=2"],
    )
    as_dict = {k: {p.name: p.value for p in v} for k, v in params.items()}
    assert as_dict == {
        "nominal_model": {"model_dir": "/m/n", "diagnostics_period_s": 2},
        "classifier": {"model_dir": "/m/c", "diagnostics_period_s": 2},
    }


def test_a_value_may_hold_colons() -> None:
    params = parse_parameters(["classifier"], ["classifier:model_dir=/a:b"])
    assert [(p.name, p.value) for p in params["classifier"]] == [("model_dir", "/a:b")]


@pytest.mark.parametrize("text", ["recorder:x=1", "model_dir", "classifier:=1"])
def test_bad_parameters_are_refused_with_the_reason(text: str) -> None:
    with pytest.raises(ValueError, match="-p"):
        parse_parameters(["classifier"], [text])
