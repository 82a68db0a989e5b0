"""The fleet's trend test and label-timeline comparison, without a cluster."""

from __future__ import annotations

import numpy as np
import pytest

from thruster_fdd_shore.core.fleet.compare import differences, disagreement, parse_events
from thruster_fdd_shore.core.fleet.trends import find_trends, mann_kendall, theil_sen

DAY_S = 86400.0


def test_mann_kendall_and_theil_sen_on_a_clean_decrease():
    t = np.arange(10) * 2 * DAY_S
    y = 1.0 - 0.01 * np.arange(10)
    s, z, p = mann_kendall(t, y)
    assert s == -45
    assert z < -3.5
    assert p < 1e-3
    assert theil_sen(t, y) * 30 * DAY_S == pytest.approx(-0.15)


def test_ties_and_constant_series_give_no_trend():
    t = np.arange(8) * DAY_S
    assert mann_kendall(t, np.ones(8))[2] == 0.5
    assert not find_trends({"a/t0": (t, np.ones(8))})["a/t0"].flagged


def test_family_wise_false_alarm_rate_is_at_most_alpha():
    rng = np.random.default_rng(0)
    t = np.arange(10) * DAY_S
    runs, m = 2000, 6
    alarms = 0
    for _ in range(runs):
        series = {f"v/t{k}": (t, rng.normal(0.97, 0.01, 10)) for k in range(m)}
        alarms += any(tr.flagged for tr in find_trends(series, alpha=0.05).values())
    assert alarms / runs <= 0.05


def test_too_few_recordings_are_not_tested():
    t = np.arange(5) * DAY_S
    assert find_trends({"a/t0": (t, -np.arange(5.0))}) == {}


def test_disagreement_is_the_share_of_time_labels_differ():
    a = "20.000:nominal_15v;60.000:biofouling"
    b = "20.000:nominal_15v;80.000:biofouling"
    assert parse_events(a) == [(20.0, "nominal_15v"), (60.0, "biofouling")]
    assert disagreement(a, b, 100.0) == pytest.approx(0.2)
    assert disagreement(a, a, 100.0) == 0.0


def test_differences_name_rows_whose_first_fault_changes():
    base = {"vehicle": "v", "thruster": "t0", "recording": "v/r.mcap", "digest": "d",
            "duration_s": 100.0, "start_s": 0.0, "error": ""}  # fmt: skip
    old = base | {"events": "20:nominal_15v", "first_fault_label": None, "first_fault_s": None}
    new = base | {"events": "20:nominal_15v;50:biofouling", "first_fault_label": "biofouling",
                  "first_fault_s": 50.0}  # fmt: skip
    found, compared = differences([old], [new])
    assert compared == 1
    assert found[0].new_fault == "biofouling@50s"
    assert found[0].old_fault == ""
    assert found[0].share == pytest.approx(0.5)
