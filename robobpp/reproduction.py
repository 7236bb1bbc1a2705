"""Ours beside the paper: the reproduction tables, with Spearman and mean |diff| per setting, dataset and metric.

Renderer-agnostic: :func:`compare` takes our figures keyed ``(setting, dataset, policy, metric)`` and returns
plain data (:class:`Comparison`); ``robobpp reproduce`` prints it (:func:`markdown` or a terminal table) and the
server's Reproduction page renders the same data from stored runs. Our figures come from episodes
(:func:`figures_from_results`) or from a run's aggregated metrics (:func:`with_derived`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from robobpp.core import EpisodeSpec
from robobpp.episode import EpisodeResult, run_episode
from robobpp.paper import PAPER_BASELINES, paper_tables
from robobpp.policies import Policy, load_policy
from robobpp.replay import PAPER, PAPER_SETTINGS, check_protocol, run_paper_protocol
from robobpp.scoring.metrics import METRIC_BY_KEY, aggregate, metrics_for
from robobpp.sim import Setting

#: (setting, dataset, policy, metric)
Key = tuple[str, str, str, str]

SETTING_ORDER = ("math", "physics", "execution")
DATASET_ORDER = ("repetitive", "diverse", "longboard")
#: The paper's PPH: its real robot's mean speed and the fixed grasp + release time per operation.
ROBOT_SPEED_M_S = 0.34
IDLE_S = 2.0


def run_baselines(
    specs: Iterable[EpisodeSpec],
    policy: str,
    settings: Sequence[str],
    *,
    protocol: str = PAPER,
    load: Callable[[str, EpisodeSpec], Policy] | None = None,
    setting_for: Callable[[str], Setting | str] | None = None,
) -> Iterator[list[EpisodeResult]]:
    """Per spec, in this process, the episodes of built-in ``policy`` in each of ``settings`` under ``protocol``.

    Paper protocol: one Math Pack episode, replayed in each physical setting of ``settings`` (the Math episode
    is yielded too when ``settings`` has ``math``). Closed: one episode per setting. ``load`` (a policy per
    spec) and ``setting_for`` (a setting instance per name) are hooks for experiments (bench/paper_table.py).
    """
    check_protocol(protocol)
    shared = None if load is not None else load_policy(policy)
    make = setting_for or (lambda name: name)
    for spec in specs:
        agent = load(policy, spec) if load is not None else shared
        assert agent is not None
        if protocol == PAPER:
            physical = [make(s) for s in settings if s in PAPER_SETTINGS]
            runs = run_paper_protocol(spec, agent, physical)
            yield [r for name, r in runs.items() if name in settings]
        else:
            yield [run_episode(spec, agent, make(s)) for s in settings]


def pph(decision_time: float | None, trajectory_length: float | None) -> float | None:
    """The paper's theoretical picks per hour from a run's mean Decision Time (s) and Trajectory Length (m)."""
    if decision_time is None or trajectory_length is None:
        return None
    return 3600.0 / (decision_time + trajectory_length / ROBOT_SPEED_M_S + IDLE_S)


def compared_metrics(setting: str) -> tuple[str, ...]:
    """What is compared in ``setting``: robobpp's metrics there, and PPH in Execution Pack. The paper's overall
    score is not: it is min–max normalised over the paper's twelve methods, not over the ones run here."""
    keys = tuple(m.key for m in metrics_for(setting))
    return (*keys, "pph") if setting == "execution" else keys


def with_derived(setting: str, metrics: Mapping[str, float | None]) -> dict[str, float | None]:
    """A run's aggregated metrics plus what the paper derives from them (PPH in Execution Pack)."""
    out = {k: metrics.get(k) for k in compared_metrics(setting) if k != "pph"}
    if setting == "execution":
        out["pph"] = pph(metrics.get("decision_time"), metrics.get("trajectory_length"))
    return out


def figures_from_results(results: Iterable[EpisodeResult]) -> dict[Key, float | None]:
    """Our figures per (setting, dataset, policy, metric), aggregated over the episodes as a run is."""
    runs: dict[tuple[str, str, str], list[EpisodeResult]] = {}
    for r in results:
        runs.setdefault((r.setting, r.dataset, r.policy), []).append(r)
    out: dict[Key, float | None] = {}
    for (setting, dataset, policy), rs in runs.items():
        metrics = aggregate([{**r.metrics, **r.counters} for r in rs], setting)
        for metric, value in with_derived(setting, metrics).items():
            out[(setting, dataset, policy, metric)] = value
    return out


@dataclass(frozen=True, slots=True)
class Cell:
    """One figure, ours beside the paper's (``table``: the paper table it is from)."""

    setting: str
    dataset: str
    policy: str
    metric: str
    ours: float | None
    paper: float | None
    table: str | None

    @property
    def diff(self) -> float | None:
        return None if self.ours is None or self.paper is None else self.ours - self.paper


@dataclass(frozen=True, slots=True)
class Agreement:
    """How one column agrees with the paper over the policies that have both figures."""

    setting: str
    dataset: str
    metric: str
    policies: tuple[str, ...]
    #: Spearman's rank correlation (ties: average ranks); None under 3 policies or with a constant column.
    spearman: float | None
    mean_abs_diff: float | None


@dataclass(frozen=True)
class Comparison:
    cells: tuple[Cell, ...]
    agreement: tuple[Agreement, ...]
    _cells: dict[Key, Cell] = field(init=False, repr=False, compare=False)
    _agreement: dict[tuple[str, str, str], Agreement] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:  # lookups by key: a renderer asks for every cell of a table
        object.__setattr__(
            self, "_cells", {(c.setting, c.dataset, c.policy, c.metric): c for c in self.cells}
        )
        object.__setattr__(self, "_agreement", {(a.setting, a.dataset, a.metric): a for a in self.agreement})

    @property
    def settings(self) -> tuple[str, ...]:
        return _ordered({c.setting for c in self.cells}, SETTING_ORDER)

    def datasets(self, setting: str) -> tuple[str, ...]:
        return _ordered({c.dataset for c in self.cells if c.setting == setting}, DATASET_ORDER)

    def policies(self, setting: str) -> tuple[str, ...]:
        return _ordered({c.policy for c in self.cells if c.setting == setting}, PAPER_BASELINES)

    def metrics(self, setting: str) -> tuple[str, ...]:
        return _ordered({c.metric for c in self.cells if c.setting == setting}, compared_metrics(setting))

    def cell(self, setting: str, dataset: str, policy: str, metric: str) -> Cell | None:
        return self._cells.get((setting, dataset, policy, metric))

    def agreement_of(self, setting: str, dataset: str, metric: str) -> Agreement | None:
        return self._agreement.get((setting, dataset, metric))

    def to_dict(self) -> dict[str, Any]:
        tables = paper_tables()
        return {
            "paper": tables.paper,
            "tables": tables.tables,
            "cells": [asdict(c) | {"diff": c.diff} for c in self.cells],
            "agreement": [asdict(a) for a in self.agreement],
        }


def _place(item: str, order: Sequence[str]) -> tuple[int, str]:
    """Sort key: ``order``'s items first, in its order, then the rest by name."""
    return (order.index(item) if item in order else len(order), item)


def _ordered(items: Iterable[str], order: Sequence[str]) -> tuple[str, ...]:
    return tuple(sorted(items, key=lambda x: _place(x, order)))


def ranks(values: Sequence[float]) -> np.ndarray:
    """Ranks 1..n, ties given their average rank (as Spearman's rho needs)."""
    a = np.asarray(values, dtype=np.float64)
    order = np.argsort(a, kind="stable")
    out = np.empty(len(a))
    out[order] = np.arange(1, len(a) + 1)
    for v in np.unique(a):
        tied = a == v
        out[tied] = out[tied].mean()
    return out


def spearman(x: Sequence[float], y: Sequence[float]) -> float | None:
    """Spearman's rho of two equally long columns; None when it is undefined (under 3 values, a constant)."""
    if len(x) != len(y):
        raise ValueError(f"columns of {len(x)} and {len(y)} values")
    if len(x) < 3:
        return None
    rx, ry = ranks(x), ranks(y)
    if np.ptp(rx) == 0 or np.ptp(ry) == 0:
        return None
    return float(np.corrcoef(rx, ry)[0, 1])


def compare(ours: Mapping[Key, float | None], metrics: Sequence[str] | None = None) -> Comparison:
    """Each of our figures beside the paper's, and per (setting, dataset, metric) the agreement.

    ``metrics`` limits the metrics (default: :func:`compared_metrics` of each setting, utilisation first).
    A policy the paper did not run gets ``paper=None`` and stays out of the agreement.
    """
    tables = paper_tables()
    runs = {(s, d, p) for s, d, p, _ in ours}
    cells: list[Cell] = []
    for setting, dataset, policy in runs:
        for metric in [m for m in compared_metrics(setting) if metrics is None or m in metrics]:
            value = ours.get((setting, dataset, policy, metric))
            theirs = tables.get(setting, dataset, policy, metric)
            ours_value = None if value is None or not math.isfinite(value) else float(value)
            cells.append(
                Cell(
                    setting,
                    dataset,
                    policy,
                    metric,
                    ours_value,
                    theirs.value if theirs else None,
                    theirs.table if theirs else None,
                )
            )
    cells.sort(
        key=lambda c: (
            _place(c.setting, SETTING_ORDER),
            _place(c.dataset, DATASET_ORDER),
            _place(c.policy, PAPER_BASELINES),
            _place(c.metric, compared_metrics(c.setting)),
        )
    )
    # (policy, ours, paper) of the cells where both figures exist, per (setting, dataset, metric)
    columns: dict[tuple[str, str, str], list[tuple[str, float, float]]] = {}
    for c in cells:
        columns.setdefault((c.setting, c.dataset, c.metric), [])
        if c.ours is not None and c.paper is not None:
            columns[(c.setting, c.dataset, c.metric)].append((c.policy, c.ours, c.paper))
    agreement = [
        Agreement(
            s,
            d,
            m,
            tuple(policy for policy, _, _ in both),
            spearman([ours for _, ours, _ in both], [paper for _, _, paper in both]),
            float(np.mean([abs(ours - paper) for _, ours, paper in both])) if both else None,
        )
        for (s, d, m), both in columns.items()
    ]
    return Comparison(tuple(cells), tuple(agreement))


def _fmt(metric: str, value: float | None, signed: bool = False) -> str:
    if value is None:
        return "–"
    if metric == "pph":
        return f"{value:+.0f}" if signed else f"{value:.0f}"
    return f"{value:+.3f}" if signed else f"{value:.3f}"


def label(metric: str) -> str:
    return METRIC_BY_KEY[metric].label if metric in METRIC_BY_KEY else metric.upper()


def markdown(comparison: Comparison, titles: Mapping[str, str] | None = None) -> str:
    """One Markdown table per setting and metric: policies down, per dataset paper | ours | diff across, then
    Spearman and mean |diff| per dataset."""
    titles = titles or {}
    out: list[str] = []
    for s in comparison.settings:
        datasets = comparison.datasets(s)
        for m in comparison.metrics(s):
            out.append(f"**{s.capitalize()} Pack · {label(m)}**\n")
            out.append("| policy | " + " | ".join(f"{d} paper | {d} ours | diff" for d in datasets) + " |")
            out.append("|---|" + "---:|" * (3 * len(datasets)))
            for p in comparison.policies(s):
                row = []
                for d in datasets:
                    c = comparison.cell(s, d, p, m)
                    row += [_fmt(m, c.paper), _fmt(m, c.ours), _fmt(m, c.diff, True)] if c else ["–"] * 3
                out.append(f"| {titles.get(p, p)} | " + " | ".join(row) + " |")
            for name, attr in (("Spearman", "spearman"), ("mean abs diff", "mean_abs_diff")):
                row = []
                for d in datasets:
                    a = comparison.agreement_of(s, d, m)
                    value = getattr(a, attr) if a else None
                    text = (
                        "–" if value is None else (f"{value:.2f}" if attr == "spearman" else _fmt(m, value))
                    )
                    row += ["", text, ""]
                out.append(f"| **{name}** | " + " | ".join(row) + " |")
            out.append("")
    return "\n".join(out)


__all__ = [
    "Agreement",
    "Cell",
    "Comparison",
    "Key",
    "compare",
    "compared_metrics",
    "figures_from_results",
    "markdown",
    "pph",
    "ranks",
    "run_baselines",
    "spearman",
    "with_derived",
]
