"""The compiled steps (robobpp/scoring/_kernels.c) against numpy's way and the definitions: the ranks of every
resample, the order statistics of every entry's samples, the timing noise, the bounds and the weighted min–max,
on the data a board makes and on data meant to hurt them (ties, clusters, an outlier, sorted rows, NaN,
infinities, spans of 0)."""

from __future__ import annotations

import numpy as np
import pytest

from robobpp.scoring import kernels, scores, stats

needs_kernels = pytest.mark.skipif(not kernels.BUILT, reason="robobpp.scoring._kernels not built")


def test_the_kernels_are_built() -> None:
    """CI (and a development install, CONTRIBUTING.md) builds them: its boards are computed by the kernels, which
    the tests below hold to numpy's way, not by the fallback alone."""
    assert kernels.BUILT, "robobpp.scoring._kernels is not built: install a C compiler, then pip install -e ."


def _board_scores(rng: np.random.Generator, resamples: int, entries: int) -> np.ndarray:
    """Relative scores as a board makes them: an entry's level plus resample noise, read to 12 decimals."""
    levels = rng.random(entries)[None, :] * 0.6
    return np.round(levels + rng.random((resamples, entries)) * 0.05, 12)


def _strictly_better(scores: np.ndarray) -> np.ndarray:
    return (1 + (scores[:, None, :] > scores[:, :, None]).sum(axis=2)).astype(np.int32)


def _ranks_both_ways(scores: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    by_numpy = stats._ranked_by_numpy(scores, np.empty(scores.shape, np.int32))
    return stats.rank_samples(scores), by_numpy


@pytest.mark.parametrize(
    "case",
    [
        "a board's scores",
        "ties in every row",
        "every score equal",
        "a cluster and an outlier",  # nearly every entry in one bucket: sorted by qsort, not insertion
        "sorted best first",
        "sorted worst first",
        "negative and large",
        "a single entry",
        "two entries",
        "float32",
        "a strided view",
    ],
)
def test_ranks_are_numpys_and_one_plus_the_strictly_better(case: str) -> None:
    rng = np.random.default_rng(21)
    scores = _board_scores(rng, 40, 1 if case == "a single entry" else 2 if case == "two entries" else 300)
    if case == "ties in every row":
        scores = np.round(scores, 2)
    if case == "every score equal":
        scores[:] = 0.375
    if case == "a cluster and an outlier":
        scores[:, 1:] = np.round(0.5 + scores[:, 1:] * 1e-6, 12)
        scores[:, 0] = -1e6
    if case == "sorted best first":
        scores = -np.sort(-scores, axis=1)
    if case == "sorted worst first":
        scores = np.sort(scores, axis=1)
    if case == "negative and large":
        scores = np.round(scores * 1e6 - 3e5, 6)
    if case == "float32":
        scores = scores.astype(np.float32)
    if case == "a strided view":
        scores = np.ascontiguousarray(scores.T).T  # Fortran order: copied for the kernel
    kernels, by_numpy = _ranks_both_ways(scores)
    assert np.array_equal(kernels, by_numpy)
    assert np.array_equal(kernels, _strictly_better(np.asarray(scores, np.float64)))


def test_ranks_at_a_boards_size_are_numpys() -> None:
    rng = np.random.default_rng(22)
    scores = _board_scores(rng, 20, 10_000)
    scores[:, ::7] = scores[:, 3:4]  # ties scattered over the row
    kernels, by_numpy = _ranks_both_ways(scores)
    assert np.array_equal(kernels, by_numpy)


@pytest.mark.parametrize("odd", [np.nan, np.inf, -np.inf])
def test_a_row_that_is_not_finite_is_ranked_by_numpy(odd: float) -> None:
    scores = np.array([[0.25, 0.5, 0.5, 0.75], [0.25, odd, 0.5, 0.5]])
    expected = {np.inf: [4, 1, 2, 2], -np.inf: [3, 4, 1, 1]}.get(odd, [4, 1, 2, 2])  # NaN: first, as numpy's
    assert stats.rank_samples(scores).tolist() == [[4, 2, 2, 1], expected]


def test_ranks_of_a_finite_span_too_wide_for_a_double_are_numpys() -> None:
    scores = np.array([[1.7e308, -1.7e308, 0.0]])  # each finite, their difference not
    assert stats.rank_samples(scores).tolist() == [[1, 3, 2]]


@needs_kernels
def test_the_kernels_refuse_buffers_of_the_wrong_size() -> None:
    from robobpp.scoring import _kernels

    scores, out = np.zeros((3, 4)), np.zeros((3, 4), np.int32)
    with pytest.raises(ValueError, match="scores holds 96 bytes where 128 were expected"):
        _kernels.rank_rows(scores, out, 4, 4)
    with pytest.raises(ValueError, match="out holds"):
        _kernels.rank_rows(scores, np.zeros((3, 3), np.int32), 3, 4)
    with pytest.raises(ValueError, match="non-negative"):
        _kernels.rank_rows(scores, out, -3, -4)
    with pytest.raises(TypeError):
        _kernels.rank_rows(scores, out.tobytes(), 3, 4)  # type: ignore[arg-type]  # read-only bytes
    values, at = np.zeros((2, 5)), np.array([1, 3], np.int64)
    with pytest.raises(ValueError, match="ascending"):
        _kernels.order_statistics(values, 5, at[::-1].copy(), np.empty((2, 2)))
    with pytest.raises(ValueError, match="whole rows"):
        _kernels.order_statistics(values, 3, at, np.empty((2, 2)))
    with pytest.raises(ValueError, match="out holds"):
        _kernels.order_statistics(values, 5, at, np.empty((2, 3)))


def _sorted_at(values: np.ndarray, positions: list[int]) -> np.ndarray:
    return np.sort(values, axis=1)[:, positions]


@pytest.mark.parametrize(
    "case",
    [
        "samples",
        "few distinct values",
        "every value equal",
        "sorted",
        "reversed",
        "an extreme value",
        "infinities",
        "a short row",
    ],
)
def test_order_statistics_are_what_a_sort_puts_there(case: str) -> None:
    rng = np.random.default_rng(23)
    values = rng.random((64, 1_000))
    if case == "few distinct values":
        values = rng.integers(0, 3, values.shape).astype(np.float64)
    if case == "every value equal":
        values[:] = 0.5
    if case == "sorted":
        values.sort(axis=1)
    if case == "reversed":
        values = -np.sort(-values, axis=1)
    if case == "an extreme value":
        values[:, 0] = 1e300
        values[:, 1] = -1e300
    if case == "infinities":
        values[:, ::5] = np.inf
        values[:, 1::5] = -np.inf
    if case == "a short row":
        values = values[:, :3].copy()
    n = values.shape[1]
    # an interval's four order statistics, a repeated position, both ends, and positions in one half only
    for positions in ([24, 25, 974, 975], [0, 0, n - 1], [n // 2], [1, 2, 3, 4, 5], [n - 3, n - 2]):
        at = [min(p, n - 1) for p in positions]
        assert np.array_equal(stats.order_statistics(values, at), _sorted_at(values, at))


def test_order_statistics_of_random_rows_and_positions() -> None:
    rng = np.random.default_rng(24)
    for _ in range(300):
        n = int(rng.integers(1, 400))
        values = np.round(rng.normal(size=(3, n)), int(rng.integers(0, 4)))
        at = sorted(rng.integers(0, n, size=int(rng.integers(1, 6))).tolist())
        assert np.array_equal(stats.order_statistics(values, at), _sorted_at(values, at))


def test_order_statistics_of_a_row_with_nan_are_numpys() -> None:
    values = np.array([[0.5, np.nan, 0.25, 0.75], [0.5, 0.25, 0.125, 1.0]])
    expected = np.array([[0.25, np.nan], [0.125, 1.0]])  # NaN sorts last
    assert np.array_equal(stats.order_statistics(values, [0, 3]), expected, equal_nan=True)


def test_order_statistics_refuse_positions_out_of_order_or_range() -> None:
    values = np.zeros((2, 5))
    for bad in ([3, 1], [5], [-1]):
        with pytest.raises(ValueError, match="ascending"):
            stats.order_statistics(values, bad)
    assert stats.order_statistics(values, []).shape == (2, 0)
    assert stats.order_statistics(np.zeros((0, 5)), [1]).shape == (0, 1)


@pytest.mark.parametrize("seeds", ["every entry", "some entries"])
def test_the_timing_noise_is_numpys_to_the_bit(seeds: str, monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(41)
    times = np.round(rng.random((60, 250)) * 3.0, 6)  # seconds, as a board's Decision Time samples
    drawn: list[int | None] = [int(s) for s in rng.integers(0, 2**64, size=60, dtype=np.uint64)]
    drawn[:2] = [0, 2**64 - 1]
    if seeds == "some entries":
        drawn[::4] = [None] * len(drawn[::4])  # an entry without per-group figures: no noise
    rows = np.arange(250, 500)  # resamples of the plan other than the first
    by_kernels = times.copy()
    scores.add_timing_noise(by_kernels, drawn, rows)
    monkeypatch.setattr(scores, "compiled", None)
    by_numpy = times.copy()
    scores.add_timing_noise(by_numpy, drawn, rows)
    assert by_kernels.tobytes() == by_numpy.tobytes()
    assert not np.array_equal(by_numpy, times)  # it moved them
    assert np.array_equal(by_numpy[::4], times[::4]) == (seeds == "some entries")


def test_the_timing_noise_of_seeds_as_an_array_is_the_lists() -> None:
    rng = np.random.default_rng(42)
    times = rng.random((5, 30))
    seeds = rng.integers(0, 2**64, size=5, dtype=np.uint64)
    by_array, by_list = times.copy(), times.copy()
    scores.add_timing_noise(by_array, seeds, np.arange(30))
    scores.add_timing_noise(by_list, [int(s) for s in seeds], np.arange(30))
    assert by_array.tobytes() == by_list.tobytes()
    with pytest.raises(ValueError, match="4 seeds for 5 entries"):
        scores.add_timing_noise(times, seeds[:4], np.arange(30))


@needs_kernels
def test_the_timing_noise_kernel_refuses_what_does_not_fit() -> None:
    from robobpp.scoring import _kernels

    seeds, rows = np.zeros(3, np.uint64), np.zeros(4, np.uint64)
    with pytest.raises(ValueError, match="times holds 80 bytes where 96 were expected"):
        _kernels.add_timing_noise(np.zeros((2, 5)), seeds, rows, 0.2, 0.01, *stats.SPLITMIX)


@pytest.mark.parametrize("case", ["samples", "unmeasured (NaN)", "nobody measured a resample", "infinities"])
def test_the_bounds_folded_a_tile_at_a_time_are_numpys(case: str, monkeypatch: pytest.MonkeyPatch) -> None:
    from robobpp.boards import matrix

    rng = np.random.default_rng(51)
    samples = rng.random((3, 90, 17))  # metrics × entries × resamples
    if case == "unmeasured (NaN)":
        samples[0, ::4] = np.nan
    if case == "nobody measured a resample":
        samples[1, :, 5] = np.nan
    if case == "infinities":
        samples[2, 3, :] = np.inf
        samples[2, 4, :] = -np.inf
    expected = (np.fmin.reduce(samples, axis=1), np.fmax.reduce(samples, axis=1))
    for way in ("kernels", "numpy"):
        if way == "numpy":
            monkeypatch.setattr(matrix, "compiled", None)
        low, high = np.full((2, 3, 17), np.nan)
        for start in range(0, 90, 40):  # tiles of 40, 40 and 10 entries
            matrix._fold(low, high, np.ascontiguousarray(samples[:, start : start + 40]))
        assert np.array_equal(low, expected[0], equal_nan=True), way
        assert np.array_equal(high, expected[1], equal_nan=True), way


@needs_kernels
def test_the_fold_refuses_rows_that_do_not_fit() -> None:
    from robobpp.scoring import _kernels

    with pytest.raises(ValueError, match="whole rows"):
        _kernels.fold_min_max(np.zeros((3, 5)), np.zeros(4), np.zeros(4))


def _weighted_both_ways(
    values: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    key: str,
    finish: bool,
    monkeypatch: pytest.MonkeyPatch,
) -> tuple[np.ndarray, np.ndarray]:
    start = np.round(np.random.default_rng(5).random(values.shape), 3)  # a total already holding some metrics
    by_kernels, by_numpy = start.copy(), start.copy()
    scores.add_weighted_min_max(by_kernels, values, lo, hi, key, 0.37, finish=finish)
    monkeypatch.setattr(scores, "compiled", None)
    scores.add_weighted_min_max(by_numpy, values, lo, hi, key, 0.37, finish=finish)
    return by_kernels, by_numpy


@pytest.mark.parametrize("key", ["space_utilization", "decision_time", "occupancy"])
@pytest.mark.parametrize("finish", [False, True])
@pytest.mark.parametrize(
    "case",
    ["samples", "not measured (NaN)", "a span of 0", "an infinity", "below the floor", "bounds of NaN"],
)
def test_the_weighted_min_max_is_numpys_to_the_bit(
    key: str, finish: bool, case: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Relative scores are summed from these: every bit counts (ties must tie, boards must equal the
    from-scratch ones). Decision Time: lower is better, with a floor and a least span (scores.RESOLVED)."""
    rng = np.random.default_rng(31)
    values = rng.random((50, 40)) * (2.0 if key == "decision_time" else 1.0)
    lo, hi = values.min(axis=0), values.max(axis=0)
    if case == "not measured (NaN)":
        values[::3, ::2] = np.nan
    if case == "a span of 0":
        lo[:5] = hi[:5]
    if case == "an infinity":
        values[1, :] = np.inf
        hi[:] = np.inf
    if case == "below the floor":
        values[:, :10] = 1e-4
        lo[:10] = 1e-4
    if case == "bounds of NaN":
        lo[::4], hi[::3] = np.nan, np.nan
    by_kernels, by_numpy = _weighted_both_ways(values, lo, hi, key, finish, monkeypatch)
    assert by_kernels.tobytes() == by_numpy.tobytes()


@needs_kernels
def test_the_weighted_min_max_refuses_what_does_not_fit() -> None:
    from robobpp.scoring import _kernels

    values, bounds = np.zeros((3, 4)), np.zeros(4)
    with pytest.raises(ValueError, match="whole rows"):
        _kernels.add_weighted_min_max(
            values, np.zeros(3), bounds, np.zeros((3, 4)), 1.0, 0.0, 0.0, False, True, False
        )
    with pytest.raises(ValueError, match="total holds"):
        _kernels.add_weighted_min_max(
            values, bounds, bounds, np.zeros((3, 3)), 1.0, 0.0, 0.0, False, True, False
        )
