"""Leaderboard scoring (docs/benchmark.md, "Scoring and uncertainty"): two scores, each with a bootstrap interval, and rank intervals.

* The **relative** score is the paper's: each metric min–max normalised over the valid complete entries of
  the board, weighted per setting. It ranks the board, and it moves when entries arrive or leave.
* The **stable** score normalises each metric against fixed, versioned anchors (:data:`ANCHORS`), so an
  entry's stable score never changes when others arrive; it is shown beside the relative one.

Intervals come from :mod:`robobpp.scoring.stats`: one seeded, paired bootstrap over groups per board; each
resample re-aggregates every entry's run figures, re-normalises and re-ranks the board.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robobpp.scoring import stats
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


#: Version of the stable score's anchors; a change of any bound is a new version, never an edit.
ANCHORS_VERSION = "anchors-v1"
#: Per metric: the raw value that scores 0 and the one that scores 1 (clipped outside), and the scale.
#: Decision Time is anchored on a log scale (10 s → 0, 1 ms → 1): policies differ by orders of magnitude.
ANCHORS: dict[str, tuple[float, float, str]] = {
    "space_utilization": (0.0, 1.0, "linear"),
    "occupancy": (0.0, 1.0, "linear"),
    "decision_time": (10.0, 0.001, "log"),
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
    with np.errstate(invalid="ignore", divide="ignore"):
        if scale == "log":
            out = (np.log(np.maximum(values, 1e-12)) - math.log(zero)) / (math.log(one) - math.log(zero))
        else:
            out = (values - zero) / (one - zero)
    np.clip(out, 0.0, 1.0, out=out)
    out[np.isnan(out)] = 0.0
    return out


def stable_scores(entries: Sequence[Mapping[str, object]], setting: str) -> list[float]:
    """Each entry's stable score from its own raw metrics alone (no other entry can move it)."""
    total = np.zeros(len(entries))
    for key, weight in WEIGHTS[setting].items():
        total += weight * anchored(_column(entries, key), key)
    return [round(float(v), 12) for v in total]


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


def normalize(values: Sequence[float | None], better: str) -> list[float]:
    """Min–max to [0, 1], higher = better; all-equal → 0; a missing value scores 0 (the worst)."""
    present = [v for v in values if v is not None]
    if not present:
        return [0.0] * len(values)
    lo, hi = min(present), max(present)
    span = hi - lo
    out = []
    for v in values:
        if v is None or span <= 0:
            out.append(0.0)
        elif better == "up":
            out.append((v - lo) / span)
        else:
            out.append((hi - v) / span)
    return out


def competition_ranks(scores: Sequence[float]) -> list[int]:
    """1 + the number of strictly better scores ("1, 2, 2, 4"), in O(n log n)."""
    values = np.asarray(scores, dtype=np.float64)
    if len(values) > 64 and not np.isnan(values).any():  # numpy: 10,000 scores on every board update
        descending = np.sort(-values)
        return (np.searchsorted(descending, -values, side="left") + 1).tolist()
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
    n = len(entries)
    normalized: list[dict[str, float]] = [{} for _ in range(n)]
    scores = [0.0] * n
    for key, weight in weights.items():
        column = normalize([_finite(e.get(key)) for e in entries], METRIC_BY_KEY[key].better)
        for i, value in enumerate(column):
            normalized[i][key] = value
            scores[i] += weight * value
    scores = [round(s, 12) for s in scores]  # ties must tie despite float summation order
    ranks = competition_ranks(scores)
    return [Scored(normalized[i], scores[i], ranks[i]) for i in range(n)]


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


def _min_max_rows(samples: np.ndarray, better: str) -> np.ndarray:
    """Min–max of each resample (row) over the entries, as :func:`normalize` does for one list."""
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN row: nobody measured it
        lo = np.nanmin(samples, axis=1, keepdims=True)
        hi = np.nanmax(samples, axis=1, keepdims=True)
        span = hi - lo
        out = (samples - lo) / span if better == "up" else (hi - samples) / span
    return np.where(np.isfinite(out) & (span > 0), out, 0.0)


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
        relative += weight * _min_max_rows(samples, METRIC_BY_KEY[key].better)
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
