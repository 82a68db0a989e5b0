"""The T200-world patrol study a user re-runs: its tables count what the decisions published."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from thruster_fdd.core.artifact import default_models_dir
from thruster_fdd.core.diagnosis.stream import UNIT_ALLOWANCE
from thruster_fdd_shore.core.diagnosis.offline import QUIET_TOLERANCE

T200_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "t200"


@pytest.mark.slow
@pytest.mark.skipif(not T200_DATA.is_dir(), reason=f"T200 measurements not found at {T200_DATA}")
def test_the_t200_study_counts_healthy_time_before_the_onset(load_script, tmp_path: Path) -> None:
    load_script("t200_world")  # the siblings it imports
    load_script("patrol_study")
    study = load_script("t200_study")
    # The committed models stand in for trained ones: the test checks the bookkeeping.
    args = ["--out", str(tmp_path), "--models", str(default_models_dir()),
            "--healthy-runs", "2", "--healthy-s", "120", "--faulty-runs", "3",
            "--faulty-s", "150", "--onset-s", "60", "--jobs", "1"]  # fmt: skip
    assert study.main(args) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["healthy"]["units"] == 5
    assert summary["healthy"]["hours"] == pytest.approx((2 * 120 + 3 * 60) / 3600)
    assert summary["healthy"]["episodes_per_hour_upper95"] > 0
    assert set(summary["faulty"]) == {"broken_blade_1", "broken_blade_2", "biofouling"}
    runs = json.loads((tmp_path / "runs.json").read_text())
    assert [r["fault"] for r in runs[2:]] == ["broken_blade_1", "broken_blade_2", "biofouling"]
    assert all(r["fault_s"] <= r["healthy_s"] for r in runs)
    assert (tmp_path / "summary.md").read_text().startswith("Classifier `classifier-")
    quiet = [r["quiet_allowance"] for r in runs if r["quiet_allowance"] is not None]
    if quiet:
        assert summary["healthy"]["quiet_allowance_largest"] == max(quiet)
        assert summary["healthy"]["quiet_allowance_largest_unit"] in {r["seed"] for r in runs}
    for r in runs:  # a stretch published a fault exactly when it needs a larger allowance
        if r["fault_s"] > 0:
            assert r["quiet_allowance"] > UNIT_ALLOWANCE, r["seed"]
        elif r["quiet_allowance"] is not None:
            assert r["quiet_allowance"] <= UNIT_ALLOWANCE + QUIET_TOLERANCE, r["seed"]
    assert summary["unit_allowance"] == UNIT_ALLOWANCE
    assert study.main([*args, "--unit-allowance", "-1"]) == 2
