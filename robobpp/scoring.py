"""Leaderboard scoring (BENCHMARK.md §5): min–max normalised metrics, weighted per setting.

Scores are relative — adding an entry can change every other entry's score — so only raw metrics are
stored and this module runs on every read.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from robobpp.metrics import METRIC_BY_KEY

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
