"""Leaderboard scoring (docs/benchmark.md, "Scoring and uncertainty"): two scores, each with a bootstrap interval, and rank intervals.

* The **relative** score is the paper's: each metric min–max normalised over the valid complete entries of
  the board, weighted per setting. It ranks the board, and it moves when entries arrive or leave. Decision
  Time is normalised under what its measurement resolves (:data:`RESOLVED`, :func:`min_max`): a time below the
  floor counts as the floor, and its min–max spans at least a robot cycle, as the paper's does.
* The **stable** score normalises each metric against fixed, versioned anchors (:data:`ANCHORS`), so an
  entry's stable score never changes when others arrive; it is shown beside the relative one.

Intervals come from :mod:`robobpp.scoring.stats`: one seeded, paired bootstrap over groups per board; each
resample re-aggregates every entry's run figures, moves its Decision Time by a seeded draw within the
resolution (:func:`timed`), re-normalises and re-ranks the board.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robobpp.scoring import stats
from robobpp.scoring.kernels import compiled
from robobpp.scoring.metrics import METRIC_BY_KEY

#: Weights of each metric in a setting's score (each row sums to 1).
WEIGHTS: dict[str, dict[str, float]] = {
    "math": {"space_utilization": 0.60, "occupancy": 0.26, "decision_time": 0.14},
    "physics": {
        "space_utilization": 0.43,
        "occupancy": 0.19,
        "decision_time": 0.10,
        "local_stability": 0.09,
        "static_stability": 0.19,
    },
    "execution": {
        "space_utilization": 0.35,
        "occupancy": 0.15,
        "decision_time": 0.08,
        "local_stability": 0.07,
        "static_stability": 0.15,
        "trajectory_length": 0.08,
        "collapsed_placement": 0.07,
        "dangerous_operation": 0.05,
    },
}


#: What a Decision Time measurement resolves: ± (``DECISION_RESOLUTION_S`` + ``DECISION_RESOLUTION_SHARE`` × the
#: time). On a real server of the project's 2-core test machine under load, DBL placing alike measured 0.8–6.3 ms
#: built in and 3.2–17.8 ms served by a participant, and a policy sleeping 0.2 s a box 164–240 ms
#: (BENCHMARKS.md, "Decision Time: built-ins served, and what a measurement resolves"). The bootstrap moves each
#: entry's time by a seeded uniform draw within it (docs/benchmark.md, "Scoring and uncertainty").
DECISION_RESOLUTION_S = 0.010
DECISION_RESOLUTION_SHARE = 0.2
#: A Decision Time below this counts as this (s), in the relative score and the stable one: twice the
#: resolution, so times the measurement cannot tell from none are equal in every resample, and times below it
#: equal at the point. 20 ms is 0.2 % of a robot cycle: no throughput a packer would notice.
DECISION_FLOOR_S = 2 * DECISION_RESOLUTION_S
#: The least span (s) of the relative score's Decision Time min–max: about one robot cycle (3600 / picks per
#: hour: 9–11 s for the paper's fast methods), and the paper's own span (its methods, 1 ms to 8–14 s). On a
#: board of millisecond policies the plain min–max would spend Decision Time's whole weight on noise.
DECISION_MIN_SPAN_S = 10.0
#: Decimals to which the relative min–max reads every figure: a run's mean summed in another order (its episodes
#: finishing in another order) differs in the last bit, 0.15685691666666668 against 0.15685691666666665 for the
#: same placements, and the min–max stretched that over the metric's whole weight (0.86 of a Math score).
EQUAL_DECIMALS = 12
#: Per metric normalised under a measurement resolution: (floor, least span) of its relative min–max.
RESOLVED: dict[str, tuple[float, float]] = {"decision_time": (DECISION_FLOOR_S, DECISION_MIN_SPAN_S)}

#: Version of the stable score's anchors; a change of any bound is a new version, never an edit.
#: anchors-v2: Decision Time scores 1 at the floor (20 ms), not at 1 ms (anchors-v1), which turned a few
#: milliseconds of timing noise into 0.01 of stable score.
ANCHORS_VERSION = "anchors-v2"
#: Per metric: the raw value that scores 0 and the one that scores 1 (clipped outside), and the scale.
#: Decision Time is anchored on a log scale (10 s → 0, the floor → 1): policies differ by orders of magnitude.
ANCHORS: dict[str, tuple[float, float, str]] = {
    "space_utilization": (0.0, 1.0, "linear"),
    "occupancy": (0.0, 1.0, "linear"),
    "decision_time": (10.0, DECISION_FLOOR_S, "log"),
    "local_stability": (0.05, 0.0, "linear"),
    "static_stability": (0.0, 1.0, "linear"),
    "trajectory_length": (10.0, 0.0, "linear"),
    "collapsed_placement": (1.0, 0.0, "linear"),
    "dangerous_operation": (1.0, 0.0, "linear"),
}
#: Which score orders the board (the paper's); the other is shown beside it.
RANKED_BY = "relative"


def anchored(values: np.ndarray, key: str) -> np.ndarray:
    """The stable normalisation of raw values (0..1, higher = better; NaN → 0, the worst)."""
    zero, one, scale = ANCHORS[key]
    # one new array, then in place (a board's full computation anchors its grid's 2.5 million samples a
    # board); fmax then fmin clip as ``clip`` does and send NaN to 0 in the same two passes (a zero's sign
    # may differ from clip's, which no sum of these scores can show: they are added to zeros)
    with np.errstate(invalid="ignore", divide="ignore"):
        if scale == "log":
            out: np.ndarray = np.maximum(values, 1e-12, dtype=np.float64)
            np.log(out, out=out)
            out -= math.log(zero)
            out /= math.log(one) - math.log(zero)
        else:
            out = np.subtract(values, zero, dtype=np.float64)
            out /= one - zero
    np.fmax(out, 0.0, out=out)
    np.fmin(out, 1.0, out=out)
    return out


def stable_scores(entries: Sequence[Mapping[str, object]], setting: str) -> list[float]:
    """Each entry's stable score from its own raw metrics alone (no other entry can move it)."""
    columns = [_column(entries, key) for key in WEIGHTS[setting]]
    return stable_scores_of(np.column_stack(columns) if columns else np.zeros((len(entries), 0)), setting)


def stable_scores_of(points: np.ndarray, setting: str) -> list[float]:
    """:func:`stable_scores` of entries given as their metrics: entries × the setting's metrics (in the order
    of its weights), NaN = missing."""
    total = np.zeros(points.shape[0])
    for j, (key, weight) in enumerate(WEIGHTS[setting].items()):
        total += weight * anchored(points[:, j], key)
    return [round(v, 12) for v in total.tolist()]


def _column(entries: Sequence[Mapping[str, object]], key: str) -> np.ndarray:
    return np.array([np.nan if (v := _finite(e.get(key))) is None else v for e in entries], dtype=np.float64)


@dataclass(frozen=True, slots=True)
class Scored:
    """One entry's normalised metrics (0..1, higher is better), weighted score and rank (1 = best)."""

    normalized: dict[str, float]
    score: float
    rank: int


def _finite(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def min_max(values: np.ndarray, lo: np.ndarray, hi: np.ndarray, key: str) -> np.ndarray:
    """The relative normalisation of metric ``key``'s ``values`` under the board's min ``lo`` and max ``hi``
    (arrays that broadcast): 0..1, higher = better; 0 where a value is missing (NaN) or the span is 0.

    The one rule every path uses (points, resamples, the board engine's incremental updates). A metric in
    :data:`RESOLVED` (Decision Time) is normalised as the paper's min–max over methods from 1 ms to 14 s
    is: a value below the floor counts as the floor, and the span is at least the least span — so only
    slow methods lose, and a difference below what the measurement resolves is no difference. Every figure is
    read to :data:`EQUAL_DECIMALS` decimals, so float summation noise is no difference either."""
    # one new array for the values, then in place (a board's full computation normalises 80 million samples)
    out = np.round(np.asarray(values, dtype=np.float64), EQUAL_DECIMALS)
    lo, hi = np.round(lo, EQUAL_DECIMALS), np.round(hi, EQUAL_DECIMALS)
    with np.errstate(invalid="ignore", divide="ignore"):
        if key in RESOLVED:
            floor, least = RESOLVED[key]
            np.maximum(out, floor, out=out)
            lo, hi = np.maximum(lo, floor), np.maximum(hi, floor)
            span = np.maximum(hi - lo, least)  # NaN stays NaN
        else:
            span = hi - lo
        if METRIC_BY_KEY[key].better == "up":
            np.subtract(out, lo, out=out)
        else:
            np.subtract(hi, out, out=out)
        np.divide(out, span, out=out)
        spans_usable = bool(np.all(span > 0))
        # one summing pass tells that every value is finite (a sum of finite values that overflows only sends
        # it the long way): the mask and its pass are then made only where some value is not
        if spans_usable and np.isfinite(np.add.reduce(out, axis=None)):
            return out
    unusable = ~np.isfinite(out)
    if not spans_usable:
        unusable |= ~(span > 0)
    np.copyto(out, 0.0, where=unusable)
    return out


def add_weighted_min_max(
    total: np.ndarray,
    values: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    key: str,
    weight: float,
    *,
    finish: bool = False,
) -> None:
    """``total += weight * min_max(values, lo, hi, key)`` in place, for ``values`` and ``total`` of entries ×
    resamples and ``lo``, ``hi`` per resample: one metric's share of the relative scores; ``finish``: then read
    the total to :data:`EQUAL_DECIMALS` decimals. In one pass where the kernels are built
    (``_kernels.add_weighted_min_max``: the same operations in the same order, so the same bits), else by
    :func:`min_max`'s passes."""
    fits = values.dtype == total.dtype == np.float64 and values.shape == total.shape == (len(total), len(lo))
    if compiled is not None and fits and values.flags.c_contiguous and total.flags.c_contiguous:
        floor, least = RESOLVED.get(key, (-math.inf, 0.0))
        bounds = np.ascontiguousarray(lo, np.float64), np.ascontiguousarray(hi, np.float64)
        up = METRIC_BY_KEY[key].better == "up"
        compiled.add_weighted_min_max(
            values, *bounds, total, weight, floor, least, key in RESOLVED, up, finish
        )
        return
    normalised = min_max(values, lo, hi, key)
    normalised *= weight
    total += normalised
    if finish:
        np.round(total, EQUAL_DECIMALS, out=total)


def normalize(values: Sequence[float | None], key: str) -> list[float]:
    """Metric ``key``'s values normalised over themselves (:func:`min_max`); None scores 0 (the worst)."""
    column = np.array([np.nan if v is None else v for v in values], dtype=np.float64).reshape(len(values))
    if not np.isfinite(column).any():
        return [0.0] * len(values)
    finite = column[np.isfinite(column)]
    normalised: list[float] = min_max(column, finite.min(), finite.max(), key).tolist()
    return normalised


def timed(samples: np.ndarray, seeds: Sequence[int | None], rows: np.ndarray | None = None) -> np.ndarray:
    """Decision Time samples (resamples, entries) with each entry's timing noise (:func:`add_timing_noise`),
    as a new array; ``rows``: which resamples of the plan these are (default: all, in order)."""
    out = samples.copy()
    add_timing_noise(out.T, seeds, np.arange(samples.shape[0]) if rows is None else rows)
    return out


def add_timing_noise(times: np.ndarray, seeds: Sequence[int | None] | np.ndarray, rows: np.ndarray) -> None:
    """Move Decision Time samples (entries, resamples ``rows`` of the plan), in place, by each entry's timing
    noise: a uniform draw within ± the resolution of each sample's time (:func:`stats.timing_noise`;
    ``seeds``: each entry's :func:`stats.timing_seed`, None = no noise: an entry without per-group figures).
    Element-wise, so an entry's samples are the same computed alone or among others, by ``score_board`` or
    by the board engine."""
    if isinstance(seeds, np.ndarray):  # every entry seeded (a board's measured entries): no Python int each
        if len(seeds) != times.shape[0]:
            raise ValueError(f"{len(seeds)} seeds for {times.shape[0]} entries: an array seeds every entry")
        noisy: list[int] = []
        drawn = seeds.astype(np.uint64, copy=False)
    else:
        noisy = [i for i, seed in enumerate(seeds) if seed is not None]
        if not noisy:
            return
        drawn = np.array([seeds[i] for i in noisy], dtype=np.uint64)
    everyone = len(drawn) == times.shape[0]
    t = times if everyone else times[noisy]  # every entry (the usual case): no copy
    if compiled is not None and t.dtype == np.float64 and t.flags.c_contiguous and t.shape[1] == len(rows):
        # the draws and the move in one pass (``_kernels.add_timing_noise``: the same steps, so the same bits)
        plan_rows = np.asarray(rows, dtype=np.uint64)
        share, resolution = DECISION_RESOLUTION_SHARE, DECISION_RESOLUTION_S
        compiled.add_timing_noise(t, drawn, plan_rows, share, resolution, *stats.SPLITMIX)
    else:
        moved = DECISION_RESOLUTION_SHARE * t
        moved += DECISION_RESOLUTION_S
        moved *= stats.timing_noise(drawn, rows)
        t += moved
    if not everyone:
        times[noisy] = t


def competition_ranks(scores: Sequence[float]) -> list[int]:
    """1 + the number of strictly better scores ("1, 2, 2, 4"), in O(n log n)."""
    values = np.asarray(scores, dtype=np.float64)
    if len(values) > 64 and not np.isnan(values).any():  # numpy: 10,000 scores on every board update
        descending = np.sort(-values)
        ranks: list[int] = (np.searchsorted(descending, -values, side="left") + 1).tolist()
        return ranks
    order = sorted(range(len(scores)), key=lambda i: -scores[i])
    ranks = [0] * len(scores)
    for position, i in enumerate(order):
        tied = position > 0 and scores[order[position - 1]] == scores[i]
        ranks[i] = ranks[order[position - 1]] if tied else position + 1
    return ranks


def score_entries(entries: Sequence[Mapping[str, object]], setting: str) -> list[Scored]:
    """Score the entries of one leaderboard (one dataset × setting); results follow the input order."""
    try:
        weights = WEIGHTS[setting]
    except KeyError:
        raise ValueError(f"unknown setting {setting!r}; expected one of {', '.join(WEIGHTS)}") from None
    columns = {key: normalize([_finite(e.get(key)) for e in entries], key) for key in weights}
    scores = weighted_sum(columns, weights)
    ranks = competition_ranks(scores)
    return [
        Scored({key: column[i] for key, column in columns.items()}, scores[i], ranks[i])
        for i in range(len(entries))
    ]


def weighted_sum(normalized: Mapping[str, Sequence[float]], weights: Mapping[str, float]) -> list[float]:
    """Each entry's score from its normalised metrics (``normalized``: per metric, one value per entry), rounded
    to 12 decimals: ties must tie despite float summation order."""
    n = len(next(iter(normalized.values()), []))
    totals = [0.0] * n
    for key, weight in weights.items():
        for i, value in enumerate(normalized[key]):
            totals[i] += weight * value
    return [round(t, 12) for t in totals]


@dataclass(slots=True)
class BoardScores:
    """One board scored with intervals. Lists follow the input order; ``samples`` (``stable_samples``) are
    the relative (stable) scores under each resample, resamples × entries in float32, for sums of boards."""

    scored: list[Scored]
    score_ci: list[tuple[float, float]]
    rank_ci: list[tuple[int, int] | None]
    stable: list[float]
    stable_ci: list[tuple[float, float]]
    metric_ci: list[dict[str, tuple[float, float] | None]]
    samples: np.ndarray = field(repr=False)
    stable_samples: np.ndarray = field(repr=False)


def _min_max_rows(samples: np.ndarray, key: str) -> np.ndarray:
    """Min–max of each resample (row) over the entries, as :func:`normalize` does for one list."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN row: nobody measured it
        lo = np.nanmin(samples, axis=1, keepdims=True)
        hi = np.nanmax(samples, axis=1, keepdims=True)
    return min_max(samples, lo, hi, key)


def score_board(
    entries: Sequence[Mapping[str, Any]],
    setting: str,
    *,
    resamples: int = stats.RESAMPLES,
    seed: int = stats.SEED,
) -> BoardScores:
    """Score valid complete entries (``{"metrics", "figures"}``) with intervals and rank intervals.

    Entries whose ``figures`` are missing or cover other groups than the first entry's keep their point
    metrics in every resample (no interval of their own).
    """
    metrics = [e.get("metrics") or {} for e in entries]
    scored = score_entries(metrics, setting)
    n = len(entries)
    if n == 0:
        empty = np.zeros((resamples, 0), dtype=np.float32)
        return BoardScores([], [], [], [], [], [], empty, empty)
    ids = next((e["figures"]["ids"] for e in entries if e.get("figures")), None)
    counts = stats.resample_counts(len(ids), resamples, seed) if ids else np.ones((resamples, 1))
    usable = [bool(e.get("figures")) and e["figures"]["ids"] == ids for e in entries]
    relative = np.zeros((resamples, n))
    stable = np.zeros((resamples, n))
    metric_ci: list[dict[str, tuple[float, float] | None]] = [{} for _ in range(n)]
    for key, weight in WEIGHTS[setting].items():
        point = _column(metrics, key)
        if ids:
            samples = stats.metric_samples([e.get("figures") or {} for e in entries], key, counts)
            samples[:, ~np.array(usable, dtype=bool)] = point[~np.array(usable, dtype=bool)]
        else:
            samples = np.tile(point, (resamples, 1))
        lo, hi = stats.interval(samples)
        for i in range(n):
            metric_ci[i][key] = (float(lo[i]), float(hi[i])) if usable[i] and np.isfinite(lo[i]) else None
        if key in RESOLVED and ids:  # the metric's own interval is the groups'; the scores' adds timing noise
            figures = [((e.get("figures") or {}).get("values") or {}).get(key) for e in entries]
            seeds = [
                stats.timing_seed(f) if ok and f else None for f, ok in zip(figures, usable, strict=True)
            ]
            samples = timed(samples, seeds)
        relative += weight * _min_max_rows(samples, key)
        stable += weight * anchored(samples, key)
    relative = np.round(relative, 12)
    score_lo, score_hi = stats.interval(relative)
    stable_lo, stable_hi = stats.interval(stable)
    no_ranks = np.zeros(0, dtype=np.int64)
    rank_lo, rank_hi = stats.rank_interval(stats.rank_samples(relative)) if n else (no_ranks, no_ranks)
    return BoardScores(
        scored=scored,
        score_ci=[(float(a), float(b)) for a, b in zip(score_lo, score_hi, strict=True)],
        rank_ci=[(int(a), int(b)) for a, b in zip(rank_lo, rank_hi, strict=True)],
        stable=stable_scores(metrics, setting),
        stable_ci=[(float(a), float(b)) for a, b in zip(stable_lo, stable_hi, strict=True)],
        metric_ci=metric_ci,
        samples=relative.astype(np.float32),
        stable_samples=stable.astype(np.float32),
    )
