"""Scoring (docs/benchmark.md, "Scoring and uncertainty"): min–max per metric, direction, weights, ties, missing values; the stable
score; bootstrap intervals, rank intervals and paired differences."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robobpp.scoring import stats
from robobpp.scoring.metrics import metrics_for
from robobpp.scoring.scores import (
    ANCHORS,
    WEIGHTS,
    anchored,
    competition_ranks,
    normalize,
    score_board,
    score_entries,
)


@pytest.mark.parametrize("setting", ["math", "physics", "execution"])
def test_weights_cover_the_settings_metrics_and_sum_to_one(setting: str) -> None:
    assert set(WEIGHTS[setting]) == {m.key for m in metrics_for(setting)}
    assert math.isclose(sum(WEIGHTS[setting].values()), 1.0)


def test_lower_is_better_metrics_are_flipped() -> None:
    assert normalize([1.0, 2.0, 3.0], "local_stability") == [1.0, 0.5, 0.0]
    assert normalize([1.0, 2.0, 3.0], "space_utilization") == [0.0, 0.5, 1.0]


def test_a_metric_equal_for_all_entries_scores_zero() -> None:
    assert normalize([0.7, 0.7], "space_utilization") == [0.0, 0.0]
    scored = score_entries([{"space_utilization": 0.5, "occupancy": 0.8, "decision_time": 0.1}] * 3, "math")
    assert [s.score for s in scored] == [0.0, 0.0, 0.0] and [s.rank for s in scored] == [1, 1, 1]


def test_math_score_is_the_weighted_sum() -> None:
    entries = [
        {"space_utilization": 0.7, "occupancy": 0.6, "decision_time": 12.0},
        {"space_utilization": 0.5, "occupancy": 0.8, "decision_time": 0.001},  # below the floor: 0.02
        {"space_utilization": 0.6, "occupancy": 0.7, "decision_time": 6.01},
    ]
    a, b, c = score_entries(entries, "math")
    assert a.score == pytest.approx(0.60)
    assert b.score == pytest.approx(0.26 + 0.14)
    assert c.score == pytest.approx(0.5)
    assert (a.rank, c.rank, b.rank) == (1, 2, 3)
    assert c.normalized == pytest.approx({"space_utilization": 0.5, "occupancy": 0.5, "decision_time": 0.5})


def test_missing_or_non_finite_values_score_as_the_worst() -> None:
    entries: list[dict[str, float | None]] = [
        {"space_utilization": 0.7, "occupancy": 0.6, "decision_time": None},
        {"space_utilization": float("nan"), "occupancy": 0.5, "decision_time": 12.0},
        {"space_utilization": 0.5, "occupancy": 0.4, "decision_time": 0.1},
    ]
    a, b, c = score_entries(entries, "math")
    assert a.normalized["decision_time"] == 0.0 and b.normalized["space_utilization"] == 0.0
    assert c.normalized["decision_time"] == 1.0


def test_competition_ranking_and_scores_change_when_an_entry_joins() -> None:
    base = [
        {"space_utilization": 0.6, "occupancy": 0.6, "decision_time": 0.1},
        {"space_utilization": 0.6, "occupancy": 0.6, "decision_time": 0.1},
        {"space_utilization": 0.4, "occupancy": 0.5, "decision_time": 0.2},
    ]
    assert [s.rank for s in score_entries(base, "math")] == [1, 1, 3]
    before = score_entries(base, "math")[2].score
    after = score_entries([*base, {"space_utilization": 0.1, "occupancy": 0.1, "decision_time": 1.0}], "math")
    assert after[2].score > before  # relative scores: computed on read, never stored


def test_execution_uses_all_eight_metrics() -> None:
    good = {
        "space_utilization": 0.8,
        "occupancy": 0.9,
        "decision_time": 0.01,
        "local_stability": 0.001,
        "static_stability": 0.99,
        "trajectory_length": 2.0,
        "collapsed_placement": 0.0,
        "dangerous_operation": 0.0,
    }
    bad = {
        "space_utilization": 0.3,
        "occupancy": 0.5,
        "decision_time": 12.0,
        "local_stability": 0.1,
        "static_stability": 0.5,
        "trajectory_length": 5.0,
        "collapsed_placement": 0.2,
        "dangerous_operation": 0.3,
    }
    g, b = score_entries([good, bad], "execution")
    assert g.score == pytest.approx(1.0) and b.score == 0.0


def test_unknown_setting_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown setting"):
        score_entries([], "juggling")


# ---- intervals (robobpp.scoring.stats; docs/benchmark.md "Scoring and uncertainty") ----------------------------------------


def _entry(rng: np.random.Generator, mean: float, groups: int) -> dict:
    """An entry with per-group utilisation drawn around ``mean`` (the spread of real groups, ~0.08)."""
    su = np.clip(rng.normal(mean, 0.08, groups), 0, 1)
    occ = np.clip(rng.normal(0.8, 0.05, groups), 0, 1)
    dt = np.abs(rng.normal(0.002, 0.0005, groups))
    values = {"space_utilization": su.tolist(), "occupancy": occ.tolist(), "decision_time": dt.tolist()}
    figures = {"ids": list(range(groups)), "values": values, "pooled": {}}
    return {"metrics": {k: float(np.mean(v)) for k, v in values.items()}, "figures": figures}


def test_intervals_shrink_as_groups_grow() -> None:
    widths = []
    for groups in (10, 40, 160):
        rng = np.random.default_rng(3)
        entries = [_entry(rng, 0.6, groups), _entry(rng, 0.55, groups), _entry(rng, 0.5, groups)]
        board = score_board(entries, "math")
        interval = board.metric_ci[0]["space_utilization"]
        assert interval is not None
        low, high = interval
        assert low <= entries[0]["metrics"]["space_utilization"] <= high
        widths.append(high - low)
    assert widths[0] > widths[1] > widths[2]
    assert widths[0] / widths[2] > 2.5  # ∝ 1/√groups: 4 in expectation


def test_intervals_are_seeded_and_rank_intervals_cover_the_rank() -> None:
    rng = np.random.default_rng(7)
    entries = [_entry(rng, m, 30) for m in (0.70, 0.69, 0.50, 0.30)]
    a, b = score_board(entries, "math"), score_board(entries, "math")
    assert a.score_ci == b.score_ci and a.rank_ci == b.rank_ci  # same data, same interval, every read
    rank_ci = [ci for ci in a.rank_ci if ci is not None]
    assert len(rank_ci) == len(a.rank_ci)  # every entry has its rank interval
    for s, (lo, hi) in zip(a.scored, rank_ci, strict=True):
        assert lo <= s.rank <= hi
    assert rank_ci[0][1] >= 2 and rank_ci[1][0] == 1  # 0.70 vs 0.69 over 30 groups: not clearly apart
    assert rank_ci[3][0] >= 3 and rank_ci[0][1] <= 2  # far behind the top two, never among them
    other = score_board(entries, "math", seed=1)
    assert other.score_ci != a.score_ci  # the seed is what fixes them


def test_stable_score_ignores_other_entries_and_relative_score_does_not() -> None:
    rng = np.random.default_rng(11)
    a, b, c = (_entry(rng, m, 20) for m in (0.6, 0.5, 0.1))
    two, three = score_board([a, b], "math"), score_board([a, b, c], "math")
    assert two.stable[:2] == three.stable[:2] and two.stable_ci[:2] == three.stable_ci[:2]
    assert two.scored[1].score != three.scored[1].score  # the paper's relative score moves
    assert 0.0 <= three.stable[2] < three.stable[0] <= 1.0


def test_anchors_map_bounds_to_zero_and_one() -> None:
    for key, (zero, one, _scale) in ANCHORS.items():
        assert anchored(np.array([zero, one, np.nan]), key).tolist() == [0.0, 1.0, 0.0]
    # log scale: 10 s … the floor (20 ms); faster counts as the floor
    assert anchored(np.array([math.sqrt(10 * 0.02)]), "decision_time")[0] == pytest.approx(0.5)
    assert anchored(np.array([0.001, 0.003]), "decision_time").tolist() == [1.0, 1.0]
    # the rule on any value: the linear or log position between the anchors, clipped to 0..1, NaN the worst
    values = np.array([-3.0, -0.0, 0.0, 0.004, 0.02, 0.3, 0.5, 0.99, 1.0, 7.0, 12.0, np.inf, -np.inf, np.nan])
    for key, (zero, one, scale) in ANCHORS.items():
        with np.errstate(invalid="ignore", divide="ignore"):
            if scale == "log":
                position = (np.log(np.maximum(values, 1e-12)) - math.log(zero)) / (
                    math.log(one) - math.log(zero)
                )
            else:
                position = (values - zero) / (one - zero)
        want = np.nan_to_num(np.clip(position, 0.0, 1.0), nan=0.0)
        assert np.array_equal(anchored(values, key), want), key


def test_paired_difference_of_a_policy_with_itself_is_zero_centred() -> None:
    rng = np.random.default_rng(5)
    a = _entry(rng, 0.6, 30)["figures"]
    same = stats.paired_difference(a, a, "space_utilization")
    assert same["difference"] == 0.0 and same["low"] == 0.0 and same["high"] == 0.0
    noisy = {
        **a,
        "values": {k: (np.array(v) + rng.normal(0, 0.02, 30)).tolist() for k, v in a["values"].items()},
    }
    d = stats.paired_difference(a, noisy, "space_utilization")
    assert d["low"] < 0 < d["high"] and abs(d["low"] + d["high"]) < 0.5 * (d["high"] - d["low"])
    better = {
        **a,
        "values": {**a["values"], "space_utilization": [v + 0.05 for v in a["values"]["space_utilization"]]},
    }
    d = stats.paired_difference(better, a, "space_utilization")
    assert d["low"] == pytest.approx(0.05) and d["high"] == pytest.approx(0.05)  # pairing removes group noise


def test_pooled_ratio_is_resampled_as_a_ratio_of_sums() -> None:
    figures = {"ids": [0, 1], "values": {}, "pooled": {"collapsed_placement": [[1.0, 10.0], [9.0, 10.0]]}}
    counts = np.array([[1.0, 1.0], [2.0, 0.0], [0.0, 2.0]])
    assert stats.metric_samples([figures], "collapsed_placement", counts)[:, 0].tolist() == [0.5, 0.1, 0.9]


def test_groups_needed_follows_the_paired_spread() -> None:
    assert stats.groups_needed(0.05, 0.05) == 8  # (1.96 + 0.84)² ≈ 7.84
    assert stats.groups_needed(0.05, 0.025) > 4 * stats.groups_needed(0.05, 0.05) - 4


def test_run_failed_share() -> None:
    assert not stats.run_failed({"completed": 27, "policy_timeout": 3}, 30)  # 10 % is allowed
    assert stats.run_failed({"completed": 26, "policy_timeout": 3, "invalid_action": 1}, 30)
    assert not stats.run_failed({"collapse": 30}, 30)  # a packing outcome, not a policy failure
    assert stats.run_failed({}, 0) and stats.run_failed(None, -1)  # an empty run is failed
    # many at once (a board sets its runs so): the same verdicts
    failures = np.array([3, 4, 0, 0, 0, 1, 2])
    episodes = np.array([30, 30, 30, 0, -1, 10, 10])
    assert stats.runs_failed(failures, episodes).tolist() == [False, True, False, True, True, False, True]


def test_an_interval_of_rounded_samples_rounds_only_its_order_statistics() -> None:
    # the grid's mean samples are rounded to 12 decimals; its interval rounds the four values it interpolates
    # between instead of every sample: the same bits, with ties and unmeasured (NaN) samples
    rng = np.random.default_rng(3)
    samples = rng.random((250, 400)) / 3.0
    samples[:, 7] = samples[0, 7]  # every resample the same
    samples[rng.random(samples.shape) < 0.02] = np.nan
    samples[:, 11] = np.nan  # never measured
    want = stats.interval(np.round(samples, 12))
    got = stats.interval(samples, decimals=12)
    for a, b in zip(want, got, strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    assert not np.array_equal(stats.interval(samples)[0], want[0], equal_nan=True)  # rounding shows


def test_competition_ranks_of_a_large_board_count_the_strictly_better() -> None:
    """1 + the number of strictly better scores, ties tied (the vectorised path of a large board)."""
    rng = np.random.default_rng(7)
    scores = np.round(rng.choice(rng.random(40), size=500), 12).tolist()  # many ties
    ranks = competition_ranks(scores)
    assert ranks == [1 + sum(t > s for t in scores) for s in scores]
    assert competition_ranks([0.5, 0.9, 0.5, 0.1]) == [2, 1, 2, 4]
