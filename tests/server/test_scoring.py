"""Scoring on read (BENCHMARK.md §5): min–max per metric, direction, weights, ties, missing values."""

from __future__ import annotations

import math

import pytest

from robobpp.metrics import metrics_for
from robobpp.scoring import WEIGHTS, normalize, score_entries


@pytest.mark.parametrize("setting", ["math", "physics", "execution"])
def test_weights_cover_the_settings_metrics_and_sum_to_one(setting: str) -> None:
    assert set(WEIGHTS[setting]) == {m.key for m in metrics_for(setting)}
    assert math.isclose(sum(WEIGHTS[setting].values()), 1.0)


def test_lower_is_better_metrics_are_flipped() -> None:
    assert normalize([1.0, 2.0, 3.0], "down") == [1.0, 0.5, 0.0]
    assert normalize([1.0, 2.0, 3.0], "up") == [0.0, 0.5, 1.0]


def test_a_metric_equal_for_all_entries_scores_zero() -> None:
    assert normalize([0.7, 0.7], "up") == [0.0, 0.0]
    scored = score_entries([{"space_utilization": 0.5, "occupancy": 0.8, "decision_time": 0.1}] * 3, "math")
    assert [s.score for s in scored] == [0.0, 0.0, 0.0] and [s.rank for s in scored] == [1, 1, 1]


def test_math_score_is_the_weighted_sum() -> None:
    entries = [
        {"space_utilization": 0.7, "occupancy": 0.6, "decision_time": 0.010},
        {"space_utilization": 0.5, "occupancy": 0.8, "decision_time": 0.001},
        {"space_utilization": 0.6, "occupancy": 0.7, "decision_time": 0.0055},
    ]
    a, b, c = score_entries(entries, "math")
    assert a.score == pytest.approx(0.60)
    assert b.score == pytest.approx(0.26 + 0.14)
    assert c.score == pytest.approx(0.5)
    assert (a.rank, c.rank, b.rank) == (1, 2, 3)
    assert c.normalized == pytest.approx({"space_utilization": 0.5, "occupancy": 0.5, "decision_time": 0.5})


def test_missing_or_non_finite_values_score_as_the_worst() -> None:
    entries = [
        {"space_utilization": 0.7, "occupancy": 0.6, "decision_time": None},
        {"space_utilization": float("nan"), "occupancy": 0.5, "decision_time": 0.2},
        {"space_utilization": 0.5, "occupancy": 0.4, "decision_time": 0.1},
    ]
    a, b, c = score_entries(entries, "math")
    assert a.normalized["decision_time"] == 0.0 and b.normalized["space_utilization"] == 0.0
    assert c.normalized["decision_time"] == 1.0


def test_competition_ranking_and_scores_change_when_an_entry_joins() -> None:
    base = [{"space_utilization": 0.6, "occupancy": 0.6, "decision_time": 0.1},
            {"space_utilization": 0.6, "occupancy": 0.6, "decision_time": 0.1},
            {"space_utilization": 0.4, "occupancy": 0.5, "decision_time": 0.2}]  # fmt: skip
    assert [s.rank for s in score_entries(base, "math")] == [1, 1, 3]
    before = score_entries(base, "math")[2].score
    after = score_entries([*base, {"space_utilization": 0.1, "occupancy": 0.1, "decision_time": 1.0}], "math")
    assert after[2].score > before  # relative scores: computed on read, never stored


def test_execution_uses_all_eight_metrics() -> None:
    good = {"space_utilization": 0.8, "occupancy": 0.9, "decision_time": 0.01, "local_stability": 0.001,
            "static_stability": 0.99, "trajectory_length": 2.0, "collapsed_placement": 0.0,
            "dangerous_operation": 0.0}  # fmt: skip
    bad = {"space_utilization": 0.3, "occupancy": 0.5, "decision_time": 1.0, "local_stability": 0.1,
           "static_stability": 0.5, "trajectory_length": 5.0, "collapsed_placement": 0.2,
           "dangerous_operation": 0.3}  # fmt: skip
    g, b = score_entries([good, bad], "execution")
    assert g.score == pytest.approx(1.0) and b.score == 0.0


def test_unknown_setting_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown setting"):
        score_entries([], "juggling")
