"""Evaluation outputs name their models; the Foxglove layout is not wired to one thruster."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from thruster_fdd.core.labels import CLASS_NAMES
from thruster_fdd_shore.core.diagnosis.evaluation import plot_confusions
from thruster_fdd_shore.core.diagnosis.table3 import table3_markdown

LAYOUT = Path(__file__).resolve().parents[3] / "src/thruster_fdd/config/foxglove_layout.json"


def _result() -> dict[str, Any]:
    n = len(CLASS_NAMES)
    eye = np.eye(n).tolist()
    stats = {
        "windows": 10,
        "balanced_accuracy": 0.9,
        "balanced_accuracy_stable": 0.95,
        "unknown_rate": 0.01,
    }
    return {
        "nominal_model_id": "nominal-narx-abc123",
        "classifier_model_id": "classifier-mlp-def456",
        "per_sample": [
            {
                "model": "MLP",
                "inputs": "residuals",
                "cv_accuracy": 0.8,
                "test_accuracy": 0.8,
                "confusion": eye,
            }
        ],
        "per_window": {
            "overall": stats,
            "per_signal": {"sine": stats},
            "confusion": np.hstack([np.eye(n), np.zeros((n, 1))]).tolist(),
        },
        "window_config": {"unit_seeds": [1, 2]},
        "onset": {
            "runs": 3,
            "never_settled": 0,
            "median_s": 20.0,
            "p95_s": 25.0,
            "max_s": 26.0,
            "per_fault": {},
        },
        "unknown": {},
    }


def test_table3_md_names_the_models() -> None:
    text = table3_markdown(_result())
    assert "nominal-narx-abc123" in text
    assert "classifier-mlp-def456" in text


def test_confusion_plots_are_written(tmp_path: Path) -> None:
    paths = plot_confusions(_result(), tmp_path)
    assert [p.name for p in paths] == ["confusion_per_sample.png", "confusion_per_window.png"]
    assert all(p.stat().st_size > 1000 for p in paths)


def _paths(layout: dict[str, Any]) -> list[str]:
    out = []
    for config in layout["configById"].values():
        out += [p["value"] for p in config.get("paths", [])]
        if "topicPath" in config:
            out.append(config["topicPath"])
    return out


def test_foxglove_layout_uses_a_variable_for_the_thruster() -> None:
    layout = json.loads(LAYOUT.read_text())
    paths = _paths(layout)
    # Panels read the merged topics filtered by $thruster (the user scripts take every
    # thruster's topic; only the health plot compares all thrusters by name).
    assert not [p for p in paths if p.startswith("/thruster/")], paths
    assert "thruster" in layout["globalVariables"]
    assert any("$thruster" in p for p in paths)


def test_foxglove_layout_plots_the_command_apart_from_the_voltage() -> None:
    layout = json.loads(LAYOUT.read_text())
    for config in layout["configById"].values():
        fields = {p["value"].rsplit(".", 1)[-1] for p in config.get("paths", [])}
        assert not {"command", "voltage_v"} <= fields, config.get("title")
