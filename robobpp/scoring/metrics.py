"""The eight metrics of docs/benchmark.md, "Metrics": definitions, per-episode computation, run aggregation."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

from robobpp.core import ContainerSpec, ContainerState, FinalBox, Placement

# Re-exported: the episode and the board modules read the physical settings here (declared in the vocabulary).
from robobpp.vocabulary import PHYSICAL as PHYSICAL
from robobpp.vocabulary import SETTINGS


@dataclass(frozen=True, slots=True)
class MetricDef:
    key: str
    label: str
    better: Literal["up", "down"]
    unit: str
    settings: tuple[str, ...]


METRICS: tuple[MetricDef, ...] = (
    MetricDef("space_utilization", "Space Utilization", "up", "", SETTINGS),
    MetricDef("occupancy", "Occupancy", "up", "", SETTINGS),
    MetricDef("decision_time", "Decision Time", "down", "s", SETTINGS),
    MetricDef("local_stability", "Local Stability", "down", "m", PHYSICAL),
    MetricDef("static_stability", "Static Stability", "up", "", PHYSICAL),
    MetricDef("trajectory_length", "Trajectory Length", "down", "m", ("execution",)),
    MetricDef("collapsed_placement", "Collapsed Placement", "down", "", ("execution",)),
    MetricDef("dangerous_operation", "Dangerous Operation", "down", "", ("execution",)),
)
METRIC_BY_KEY = {m.key: m for m in METRICS}

#: Episode counters pooled over a run (ratios of sums, not means of ratios).
POOLED = {
    "collapsed_placement": ("placements_collapsed", "placements_attempted"),
    "dangerous_operation": ("operations_dangerous", "operations"),
}


def metrics_for(setting: str) -> tuple[MetricDef, ...]:
    return tuple(m for m in METRICS if setting in m.settings)


def space_utilization(final: Sequence[FinalBox], container: ContainerSpec) -> float:
    """Volume of the boxes still in place over the container's (the closed loop's reading)."""
    return placed_volume(f for f in final if f.in_place) / container.volume


def placed_volume(final: Iterable[FinalBox]) -> float:
    """Planned volume of ``final``'s boxes, in place or not (cm³)."""
    return sum(f.planned.volume for f in final)


def occupancy(
    plan: Sequence[Placement], container: ContainerSpec, under: Sequence[float] | None = None
) -> float | None:
    """The mean, over the placements, of the volume of the boxes placed so far over the volume under the
    heightmap their planned poses make (1 cm cells, the Math Pack's heightmap): how densely the pile is
    built at each step, as the reference computes it (on its idealised heightmap). None without a box.

    ``under``: those volumes under the heightmap after each placement, when the caller kept them
    (``Setting.under_volumes``); otherwise the plan is replayed onto an empty container here."""
    if not plan:
        return None
    if under is None:
        state = ContainerState(container)
        replayed = []
        for placement in plan:
            state.add(placement)
            replayed.append(state.volume_under_heightmap())
        under = replayed
    volume = total = 0.0
    for placement, below in zip(plan, under, strict=True):
        volume += placement.volume
        total += volume / below if below > 0 else 0.0
    return total / len(plan)


def local_stability_m(final: Sequence[FinalBox]) -> float | None:
    """Mean over the boxes of |dx| + |dy| between each box's planned and actual centre, metres: the
    reference's position offset (height and attitude left out, as its collapse rule leaves them out)."""
    if not final:
        return None
    total = 0.0
    for f in final:
        (px, py, _), (ax, ay, _) = f.planned.center, f.actual.center
        total += (abs(ax - px) + abs(ay - py)) / 100.0
    return total / len(final)


def _mean(values: Iterable[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return sum(kept) / len(kept) if kept else None


def aggregate(episodes: Sequence[Mapping[str, float | None]], setting: str) -> dict[str, float | None]:
    """A run's figures: the mean over its episodes, except the pooled ratios (docs/benchmark.md, "Metrics")."""
    out: dict[str, float | None] = {}
    for m in metrics_for(setting):
        if m.key in POOLED:
            num_key, den_key = POOLED[m.key]
            num = sum(float(e.get(num_key) or 0) for e in episodes)
            den = sum(float(e.get(den_key) or 0) for e in episodes)
            out[m.key] = num / den if den else None
        else:
            out[m.key] = _mean(e.get(m.key) for e in episodes)
    return out
