"""The patrol study a user re-runs: it writes its tables, runs and reliability plot."""

from __future__ import annotations

import json
from pathlib import Path

import pytest


@pytest.mark.slow
def test_the_patrol_study_writes_its_tables(load_script, tmp_path: Path) -> None:
    study = load_script("patrol_study")
    args = ["--out", str(tmp_path), "--healthy-runs", "1", "--patrol-s", "300",
            "--faulty-runs", "1", "--faulty-s", "240", "--calibration-units", "1",
            "--demo-seeds", "1", "--jobs", "1", "--first-seed", "9900"]  # fmt: skip
    assert study.main(args) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["healthy"]["hours"] == pytest.approx(300 / 3600)
    assert set(summary["faulty"]) == {"broken_blade_1", "broken_blade_2", "biofouling"}
    assert 0.0 <= summary["calibration"]["ece"] <= 1.0
    assert summary["demo"]["seeds"] == 1
    assert (tmp_path / "summary.md").read_text().startswith("Classifier `classifier-")
    assert (tmp_path / "reliability.png").stat().st_size > 1000
    runs = json.loads((tmp_path / "runs.json").read_text())
    assert len(runs["healthy"]) == 1
    assert len(runs["faulty"]) == 3


def test_the_false_alarm_bound_is_the_poisson_upper_limit(load_script) -> None:
    study = load_script("patrol_study")
    # No event in 20 h: -ln(0.05) / 20 = 0.150 per hour.
    assert study.poisson_upper(0, 20.0) == pytest.approx(0.1498, abs=1e-3)
    assert study.poisson_upper(3, 20.0) > study.poisson_upper(0, 20.0)
