"""Resampled figures: float32 figures summed exactly, one computation whatever the stacking or the block of
resamples, ranks and order statistics by partial sorts equal to their definitions."""

from __future__ import annotations

import numpy as np
import pytest

from robobpp.boards.matrix import _order_and_interval, _row_hashes
from robobpp.scoring import stats
from robobpp.scoring.entries import (
    EntryPart,
    Stacked,
    counts,
    entry_part,
    metric_keys,
    part_seed,
    samples_of,
)
from robobpp.scoring.metrics import POOLED
from robobpp.scoring.scores import min_max

SETTING = "execution"


def _figures(rng: np.random.Generator, groups: int, holes: bool) -> dict[str, object]:
    values: dict[str, list[float | None]] = {
        key: (rng.random(groups) * scale).tolist()
        for key, scale in (
            ("space_utilization", 1.0),
            ("occupancy", 1.0),
            ("decision_time", 0.05),
            ("local_stability", 0.01),
            ("static_stability", 1.0),
            ("trajectory_length", 5.0),
        )
    }
    if holes:
        values["occupancy"][2] = None
        values["trajectory_length"][0] = None
    pooled = {
        "collapsed_placement": [
            [float(rng.integers(0, 5)), float(rng.integers(0, 40))] for _ in range(groups)
        ],
        "dangerous_operation": [[float(rng.integers(0, 3)), 40.0] for _ in range(groups)],
    }
    return {"ids": list(range(groups)), "values": values, "pooled": pooled}


def _parts(seed: int, n: int, groups: int = 30) -> tuple[list[dict[str, object]], list[EntryPart]]:
    rng = np.random.default_rng(seed)
    figures = [_figures(rng, groups, holes=k % 4 == 1) for k in range(n)]
    return figures, [entry_part(f, SETTING) for f in figures]


def test_figures_are_read_as_float32_and_their_resampled_sums_are_exact() -> None:
    values = [0.1, 1 / 3, None, 2.5e-3]
    read = stats.as_resampled(values)
    assert read.dtype == np.float64
    assert np.array_equal(read, np.array([0.1, 1 / 3, np.nan, 2.5e-3], np.float32), equal_nan=True)
    # a sum of counts × float32 figures is exact: any order of summation gives the same bits
    rng = np.random.default_rng(3)
    figures = stats.as_resampled(rng.random(30))
    plan = counts(30)
    forward = plan @ figures
    terms = plan * figures
    backward = np.zeros(plan.shape[0])
    for g in reversed(range(30)):
        backward += terms[:, g]
    assert np.array_equal(forward, backward)


def test_an_entry_has_the_same_samples_alone_stacked_and_in_any_block_of_resamples() -> None:
    _, parts = _parts(5, 12)
    top = np.stack([p.top for p in parts])
    bottom = np.stack([p.bottom for p in parts])
    plan = counts(30)
    stacked = Stacked.of(top, bottom).samples(plan)
    assert stacked.shape == (8, 12, plan.shape[0])
    weighed = Stacked.of(top, bottom).weighed  # the holes' columns sum their weights; the others count
    assert weighed.any() and (~weighed).any()
    for k, part in enumerate(parts):
        alone = samples_of(part.top[None], part.bottom[None], plan)[:, 0]
        assert np.array_equal(alone, stacked[:, k], equal_nan=True)
    rows = np.array([999, 3, 500, 4])  # a few resamples, in any order
    block = Stacked.of(top, bottom).samples(plan[rows])
    assert np.array_equal(block, stacked[:, :, rows], equal_nan=True)
    # a tile of entries at a time: the pooled metrics' weights (every entry's) and the holes' (some) are read
    # at the tile's own rows
    whole = Stacked.of(top, bottom)
    for start in range(0, 12, 5):
        stop = min(12, start + 5)
        tile = whole.tile(plan, start, stop, np.empty((8, stop - start, plan.shape[0])))
        assert np.array_equal(tile, stacked[:, start:stop], equal_nan=True)


def test_the_samples_equal_the_from_scratch_computation_on_the_recorded_figures() -> None:
    figures, parts = _parts(7, 9)
    plan = counts(30)
    samples = samples_of(np.stack([p.top for p in parts]), np.stack([p.bottom for p in parts]), plan)
    for j, key in enumerate(metric_keys(SETTING)):
        scratch = stats.metric_samples(figures, key, plan)  # (resamples, entries), from the JSON figures
        assert np.array_equal(scratch, samples[j].T, equal_nan=True), key


def test_a_pooled_ratio_with_no_denominator_drawn_is_unmeasured() -> None:
    top = np.zeros((1, 3, 8), np.float32)
    bottom = np.ones((1, 3, 8), np.float32)
    j = 6  # collapsed_placement
    assert "collapsed_placement" in POOLED
    top[0, :, j], bottom[0, :, j] = [1.0, 0.0, 2.0], [4.0, 0.0, 0.0]
    plan = np.array([[0.0, 3.0, 0.0], [1.0, 1.0, 1.0], [0.0, 1.0, 2.0]])
    out = samples_of(top, bottom, plan)[j, 0]
    assert np.isnan(out[0])  # only the group without a denominator drawn
    assert out[1] == pytest.approx(3.0 / 4.0)
    assert np.isnan(out[2])


def test_the_timing_seed_is_the_same_from_the_recorded_figures_and_from_the_part() -> None:
    figures, parts = _parts(9, 3)
    for f, part in zip(figures, parts, strict=True):
        recorded = f["values"]["decision_time"]  # type: ignore[index]
        assert stats.timing_seed(recorded) == part.seed == part_seed(part.top, part.bottom, SETTING)


def _splitmix_draw(seed: int, row: int) -> float:
    """The timing noise's draw for one entry and resample, as its documentation states it, in Python integers:
    SplitMix64 of the seed plus (row + 1) golden-ratio steps, its top 53 bits read as [0, 1), mapped to ±1."""
    mask = 2**64 - 1
    z = (seed + (row + 1) * 0x9E3779B97F4A7C15) & mask
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & mask
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & mask
    z ^= z >> 31
    return 2.0 * ((z >> 11) * 2.0**-53) - 1.0


def test_timing_noise_is_splitmix64_of_the_seed_and_the_resample() -> None:
    """Stored runs and every board must draw the same noise whatever numpy passes compute it."""
    seeds = [0, 1, 2**64 - 1, 0x0123456789ABCDEF, 2**63]
    rows = np.array([0, 1, 7, 499, 999])
    noise = stats.timing_noise(np.array(seeds, dtype=np.uint64), rows)
    expected = [[_splitmix_draw(s, int(r)) for r in rows] for s in seeds]
    assert noise.tolist() == expected
    assert noise.min() >= -1.0 and noise.max() < 1.0


@pytest.mark.parametrize("at_once", [4_000_000, 7 * 40, 1])  # one block, blocks of 7 resamples, one row each
def test_ranks_of_every_resample_are_one_plus_the_strictly_better(
    at_once: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(stats, "_RANKED_AT_ONCE", at_once)
    rng = np.random.default_rng(11)
    scores = np.round(rng.random((50, 40)), 1)  # many ties
    ranks = stats.rank_samples(scores)  # the kernels' where built (tests/scoring/test_kernels.py)
    by_numpy = stats._ranked_by_numpy(scores, np.empty(scores.shape, np.int32))  # blocks of ``at_once``
    for b in range(scores.shape[0]):
        for e in range(scores.shape[1]):
            assert ranks[b, e] == by_numpy[b, e] == 1 + int((scores[b] > scores[b, e]).sum())
    assert stats.rank_samples(np.zeros((3, 0))).shape == (3, 0)
    into = np.zeros((scores.shape[0], 2 * scores.shape[1]), np.int32)
    with pytest.raises(ValueError, match="C-contiguous int32"):  # a strided one: refused, not written astray
        stats.rank_samples(scores, out=into[:, ::2])
    assert not into.any()
    assert np.array_equal(stats.rank_samples(scores, out=into[:, : scores.shape[1]].copy()), ranks)


def _strictly_better(scores: np.ndarray) -> np.ndarray:
    """1 + the strictly better scores of each row, by definition (a score against every other)."""
    return (1 + (scores[:, None, :] > scores[:, :, None]).sum(axis=2)).astype(np.int32)


@pytest.mark.parametrize(
    ("case", "by_keys"),
    [
        ("read to 12 decimals", True),
        ("negative and above 1", True),
        ("ties in every row", True),
        ("a single entry", True),
        ("keys that would tie different scores", False),
        ("too wide for the keys", False),
    ],
)
def test_integer_keys_rank_exactly_or_leave_the_block_to_the_argsort(
    case: str, by_keys: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    rng = np.random.default_rng(14)
    scores = np.round(rng.random((30, 1 if case == "a single entry" else 300)), 12)
    if case == "negative and above 1":
        scores = np.round(scores * 5 - 2, 12)
    if case == "ties in every row":
        scores[:, ::3] = np.round(scores[:, ::3], 2)
        scores[:, 1] = scores[:, 0]
    if case == "keys that would tie different scores":  # 2e-16 apart: one key unit is 1e-12
        scores[:, 1] = scores[:, 0] + 2e-16 * (scores[:, 0] < 0.5)
    if case == "too wide for the keys":
        scores[:, 0] = 1e9
    argsorted: list[int] = []
    by_argsort = stats._ranked_by_argsort

    def counted(block: np.ndarray, out: np.ndarray) -> None:
        argsorted.append(len(block))
        by_argsort(block, out)

    monkeypatch.setattr(stats, "_ranked_by_argsort", counted)
    monkeypatch.setattr(stats, "_RANKED_AT_ONCE", 10 * scores.shape[1])  # three blocks of 10 resamples
    # numpy's way (the kernels' reference, and their fallback): the kernels rank these alike (test_kernels.py)
    ranked = stats._ranked_by_numpy(scores, np.empty(scores.shape, np.int32))
    assert np.array_equal(ranked, _strictly_better(scores))
    assert argsorted == ([] if by_keys else [10, 10, 10])


def test_a_nan_score_is_left_to_the_argsort_which_ranks_it_first() -> None:
    scores = np.array([[0.25, np.nan, 0.5, 0.5]])
    assert stats.rank_samples(scores).tolist() == [[4, 1, 2, 2]]


def test_a_rank_interval_is_numpys_lower_and_higher_quantile() -> None:
    rng = np.random.default_rng(12)
    ranks = rng.integers(1, 30, (1000, 25))
    for confidence in (0.95, 0.5, 0.9):
        low, high = stats.rank_interval(ranks, confidence)
        tail = (1 - confidence) / 2
        assert np.array_equal(low, np.quantile(ranks, tail, axis=0, method="lower"))
        assert np.array_equal(high, np.quantile(ranks, 1 - tail, axis=0, method="higher"))


def test_order_statistics_by_partial_sort_give_the_percentile_interval_bit_for_bit() -> None:
    rng = np.random.default_rng(13)
    for r in (1000, 250, 7, 1):
        rel = np.round(rng.random((30, r)), 12)
        order, (lo, hi) = _order_and_interval(rel)
        want_lo, want_hi = stats.interval(rel.T)
        assert np.array_equal(lo, want_lo) and np.array_equal(hi, want_hi)
        assert np.all(order[:, 0] <= order[:, 1]) and np.all(order[:, 2] <= order[:, 3])


def test_min_max_in_place_is_the_rule_it_states() -> None:
    rng = np.random.default_rng(14)
    values = rng.random((40, 100)) * 0.05
    values[3, 7] = np.nan
    values[:, 5] = 0.03  # a resample where everyone is equal
    lo, hi = np.nanmin(values, axis=0), np.nanmax(values, axis=0)
    for key in ("space_utilization", "decision_time", "trajectory_length"):
        kept = values.copy()
        out = min_max(values, lo, hi, key)
        assert np.array_equal(values, kept, equal_nan=True)  # the caller's samples are not touched
        assert out[3, 7] == 0.0  # missing scores the worst
        assert np.all((out >= 0) & (out <= 1))
        if (
            key == "space_utilization"
        ):  # higher is better: (value - min) / (max - min), all read to 12 decimals
            v, low, high = np.round(values, 12), np.round(lo, 12), np.round(hi, 12)
            with np.errstate(invalid="ignore", divide="ignore"):
                want = (v - low) / (high - low)
            want = np.where(np.isfinite(want) & (high - low > 0), want, 0.0)
            assert np.array_equal(out, want)
            assert np.all(out[:, 5] == 0.0)
    # every value finite, every span positive (the pass that skips the mask) and then one value infinite
    spread = rng.random((40, 100))
    lo, hi = spread.min(axis=0), spread.max(axis=0)
    want = (np.round(spread, 12) - np.round(lo, 12)) / (np.round(hi, 12) - np.round(lo, 12))
    assert np.array_equal(min_max(spread, lo, hi, "space_utilization"), want)
    spread[9, 2] = np.inf
    out = min_max(spread, lo, hi, "space_utilization")
    assert out[9, 2] == 0.0 and np.array_equal(
        np.delete(out.ravel(), 9 * 100 + 2), np.delete(want.ravel(), 902)
    )


def test_a_row_hash_changes_with_any_one_value_and_not_with_the_kind_of_nan() -> None:
    rng = np.random.default_rng(15)
    rows = rng.random((20, 17))
    rows[2, 4] = np.nan
    base = _row_hashes(rows)
    assert len(set(base.tolist())) == 20
    for i, j in ((0, 0), (2, 4), (19, 16), (7, 9)):
        moved = rows.copy()
        moved[i, j] = np.nextafter(rows[i, j], 2.0) if np.isfinite(rows[i, j]) else 0.5
        changed = _row_hashes(moved) != base
        assert changed[i] and changed.sum() == 1
    other_nan = rows.copy()
    other_nan.view(np.uint64)[2, 4] |= np.uint64(1)  # another NaN payload
    assert np.isnan(other_nan[2, 4])
    assert np.array_equal(_row_hashes(other_nan), base)
    signed = rows.copy()
    signed[5, 5] = 0.0
    negative = signed.copy()
    negative[5, 5] = -0.0
    assert np.array_equal(_row_hashes(signed), _row_hashes(negative))
