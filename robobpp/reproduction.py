"""Ours beside the paper: the reproduction tables, with Spearman and mean |diff| per setting, dataset and metric.

Renderer-agnostic: :func:`compare` takes our figures keyed ``(setting, dataset, policy, metric)`` and returns
plain data (:class:`Comparison`); ``robobpp reproduce`` prints it (:func:`markdown` or a terminal table) and the
server's Reproduction page renders the same data from stored runs. Our figures come from episodes
(:func:`figures_from_results`) or from a run's aggregated metrics (:func:`with_derived`).

Beside the figures: why each metric's figures are expected to differ (:data:`EXPECTED`), the paper's score
recomputed over the compared methods from ours and from the paper's figures (:func:`compare_scores`), and the
paper's methods robobpp does not run as paper-reported rows (:data:`PAPER_ONLY`), never compared.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from robobpp.core import EpisodeSpec
from robobpp.episode import EpisodeResult
from robobpp.paper import PAPER_BASELINES, paper_tables, place_in_order
from robobpp.policies import Policy, load_policy
from robobpp.replay import check_loop, play
from robobpp.scoring.metrics import METRIC_BY_KEY, aggregate, metrics_for
from robobpp.scoring.scores import WEIGHTS, normalize, weighted_sum
from robobpp.sim import Setting
from robobpp.vocabulary import DATASETS, PAPER, SETTINGS

#: (setting, dataset, policy, metric)
Key = tuple[str, str, str, str]

#: The paper's PPH: its real robot's mean speed and the fixed grasp + release time per operation.
ROBOT_SPEED_M_S = 0.34
IDLE_S = 2.0


@dataclass(frozen=True, slots=True)
class Expectation:
    """Why our figures of one metric are expected to differ from the paper's, and where the docs show it."""

    #: One line: the cause of the difference, not a verdict on it.
    why: str
    #: The experiment in the docs, a link relative to the repository root (``docs/<page>.md#<anchor>``).
    doc: str
    #: False: the metric measures the paper's hardware rather than the method, so its ranking is not compared
    #: (no Spearman; "not compared" where it would be). Its mean |diff| is still shown.
    ranked: bool = True


_PLANNER = Expectation(
    "Our robot's motion is planned by our planner, not the reference's OMPL RRT with its 15 s wall-clock budget.",
    "docs/execution.md",
)

#: Per compared metric (:func:`compared_metrics`): why a difference from the paper is expected.
EXPECTED: dict[str, Expectation] = {
    "space_utilization": Expectation(
        "Our groups are the public train split, the paper's its private test split; in Physics and Execution a "
        "collapse moves with a tenth of a millimetre, so single groups differ.",
        "docs/benchmark.md#two-protocols-closed-loop-and-the-papers",
    ),
    "occupancy": Expectation(
        "Computed as the reference does (the mean over placements of the placed volume over the volume under "
        "the planned heightmap); the groups differ.",
        "docs/benchmark.md#metrics",
    ),
    "decision_time": Expectation(
        "The paper's hardware and implementations, not the method: not compared (no Spearman).",
        "docs/benchmark.md#metrics",
        ranked=False,
    ),
    "local_stability": Expectation(
        "The reference's position offset (|dx|+|dy| of each box from its target). A few groups carry the mean: "
        "a toppling tower throws boxes a metre or more (MACS on Diverse: 6 of 30 groups, the rest 0.001 m); "
        "and our grid has no 2 % gap between neighbours, so a box released clear of one starts up to 5 mm off.",
        "docs/validation/physics.md#static-stability-against-the-reference",
    ),
    "static_stability": Expectation(
        "Measured on the reference's landing (a mesh box lowered 1 mm per step until it touches); the eight "
        "methods lie within a few hundredths, so their order is mostly near-ties; the default fast simulation "
        "ends the 200-step window once everything is at rest.",
        "docs/validation/physics.md#static-stability-against-the-reference",
    ),
    "trajectory_length": _PLANNER,
    "collapsed_placement": _PLANNER,
    "dangerous_operation": _PLANNER,
    "pph": Expectation(
        "Derived from Decision Time and Trajectory Length with the paper's formula, so it inherits Decision "
        "Time's hardware gap: its ranking is not compared.",
        "docs/benchmark.md#metrics",
        ranked=False,
    ),
}

#: The paper's methods robobpp does not run (TAP-Net++, AR2L, PackE, CDRL): shown with the paper's figures
#: only, as paper-reported rows, and never in an agreement or a score comparison.
PAPER_ONLY: tuple[str, ...] = tuple(m for m in paper_tables().methods if m not in PAPER_BASELINES)
#: Left out of the score comparison: Decision Time measures the paper's hardware (:data:`EXPECTED`), and PPH is
#: derived from it (PPH carries no weight in the score anyway).
SCORE_LEFT_OUT: tuple[str, ...] = ("decision_time", "pph")


def run_baselines(
    specs: Iterable[EpisodeSpec],
    policy: str,
    settings: Sequence[str],
    *,
    loop: str = PAPER,
    load: Callable[[str, EpisodeSpec], Policy] | None = None,
    setting_for: Callable[[str], Setting | str] | None = None,
) -> Iterator[list[EpisodeResult]]:
    """Per spec, in this process, the episodes of built-in ``policy`` in each of ``settings`` under ``loop``
    (:data:`robobpp.vocabulary.Loop`).

    Paper: one Math Pack episode, replayed in each physical setting of ``settings`` (the Math episode
    is yielded too when ``settings`` has ``math``). Closed: one episode per setting. ``load`` (a policy per
    spec) and ``setting_for`` (a setting instance per name) are hooks for experiments (bench/paper_table.py).
    """
    check_loop(loop)
    shared = None if load is not None else load_policy(policy)
    make = setting_for or (lambda name: name)
    for spec in specs:
        agent = load(policy, spec) if load is not None else shared
        assert agent is not None
        yield play(loop, spec, agent, [make(s) for s in settings])


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
    #: A method robobpp does not run (:data:`PAPER_ONLY`): the paper's figure alone, shown as paper-reported.
    paper_only: bool = False

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
    #: Spearman's rank correlation (ties: average ranks); None under 3 policies, with a constant column, or
    #: for a metric whose ranking is not compared (``ranked``).
    spearman: float | None
    mean_abs_diff: float | None
    #: False: the metric's ranking is not compared (:attr:`Expectation.ranked`), so it has no Spearman.
    ranked: bool = True


@dataclass(frozen=True, slots=True)
class ScoreComparison:
    """The paper's weighted min–max score over the compared methods of one (setting, dataset), computed twice:
    from our figures and from the paper's figures of the same methods and metrics (:func:`compare_scores`)."""

    setting: str
    dataset: str
    #: The scored metrics and their weights (the setting's, without :data:`SCORE_LEFT_OUT`, summing to 1).
    weights: dict[str, float]
    #: The methods with both figures of every scored metric, in the comparison's order.
    policies: tuple[str, ...]
    ours: tuple[float, ...]
    paper: tuple[float, ...]
    #: Spearman's rank correlation of the two score columns (None under 3 methods or with a constant column).
    spearman: float | None

    def of(self, policy: str) -> tuple[float, float] | None:
        """(ours, paper) score of ``policy``; None when it is not among the compared methods."""
        if policy not in self.policies:
            return None
        i = self.policies.index(policy)
        return self.ours[i], self.paper[i]


@dataclass(frozen=True)
class Comparison:
    cells: tuple[Cell, ...]
    agreement: tuple[Agreement, ...]
    scores: tuple[ScoreComparison, ...] = ()
    _cells: dict[Key, Cell] = field(init=False, repr=False, compare=False)
    _agreement: dict[tuple[str, str, str], Agreement] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:  # lookups by key: a renderer asks for every cell of a table
        object.__setattr__(
            self, "_cells", {(c.setting, c.dataset, c.policy, c.metric): c for c in self.cells}
        )
        object.__setattr__(self, "_agreement", {(a.setting, a.dataset, a.metric): a for a in self.agreement})

    @property
    def settings(self) -> tuple[str, ...]:
        return _ordered({c.setting for c in self.cells}, SETTINGS)

    def datasets(self, setting: str) -> tuple[str, ...]:
        return _ordered({c.dataset for c in self.cells if c.setting == setting}, DATASETS)

    def policies(self, setting: str) -> tuple[str, ...]:
        """The methods of ``setting``'s tables: ours in the paper's order, then the paper-reported rows."""
        run = {c.policy for c in self.cells if c.setting == setting and not c.paper_only}
        reported = {c.policy for c in self.cells if c.setting == setting and c.paper_only}
        return _ordered(run, PAPER_BASELINES) + _ordered(reported, PAPER_ONLY)

    def paper_only(self, policy: str) -> bool:
        """Whether ``policy``'s rows are paper-reported (a method robobpp does not run)."""
        return any(c.paper_only and c.policy == policy for c in self.cells)

    def metrics(self, setting: str) -> tuple[str, ...]:
        return _ordered({c.metric for c in self.cells if c.setting == setting}, compared_metrics(setting))

    def cell(self, setting: str, dataset: str, policy: str, metric: str) -> Cell | None:
        return self._cells.get((setting, dataset, policy, metric))

    def agreement_of(self, setting: str, dataset: str, metric: str) -> Agreement | None:
        return self._agreement.get((setting, dataset, metric))

    def score_of(self, setting: str, dataset: str) -> ScoreComparison | None:
        return next((c for c in self.scores if (c.setting, c.dataset) == (setting, dataset)), None)

    def to_dict(self) -> dict[str, Any]:
        tables = paper_tables()
        return {
            "paper": tables.paper,
            "tables": tables.tables,
            "cells": [asdict(c) | {"diff": c.diff} for c in self.cells],
            "agreement": [asdict(a) for a in self.agreement],
            "expected": {metric: asdict(e) for metric, e in EXPECTED.items()},
            "scores": [asdict(c) for c in self.scores],
        }


def _ordered(items: Iterable[str], order: Sequence[str]) -> tuple[str, ...]:
    return tuple(sorted(items, key=lambda x: place_in_order(x, order)))


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
    A policy the paper did not run gets ``paper=None`` and stays out of the agreement. Each (setting, dataset)
    of ours also gets the paper's figures of :data:`PAPER_ONLY` as paper-reported cells (``ours=None``), which
    no agreement counts. The score comparison (:func:`compare_scores`) always scores every metric it weighs,
    whatever ``metrics`` shows.
    """
    tables = paper_tables()
    runs = {(s, d, p) for s, d, p, _ in ours}
    ran = {p for _, _, p in runs}
    reported = {(s, d, p) for s, d, _ in runs for p in PAPER_ONLY if p not in ran}
    cells: list[Cell] = []
    for setting, dataset, policy in sorted(runs | reported):
        for metric in [m for m in compared_metrics(setting) if metrics is None or m in metrics]:
            value = ours.get((setting, dataset, policy, metric))
            theirs = tables.get(setting, dataset, policy, metric)
            paper_only = (setting, dataset, policy) in reported
            if paper_only and theirs is None:
                continue
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
                    paper_only,
                )
            )
    cells.sort(
        key=lambda c: (
            place_in_order(c.setting, SETTINGS),
            place_in_order(c.dataset, DATASETS),
            c.paper_only,
            place_in_order(c.policy, PAPER_ONLY if c.paper_only else PAPER_BASELINES),
            place_in_order(c.metric, compared_metrics(c.setting)),
        )
    )
    return Comparison(tuple(cells), _agreement(cells), compare_scores(ours))


def _agreement(cells: Sequence[Cell]) -> tuple[Agreement, ...]:
    """Per (setting, dataset, metric) of ``cells``: Spearman and mean |diff| over the policies with both figures
    (paper-reported cells have no figure of ours, so they never count); no Spearman where the metric's ranking
    is not compared."""
    # (policy, ours, paper) of the cells where both figures exist, per (setting, dataset, metric)
    columns: dict[tuple[str, str, str], list[tuple[str, float, float]]] = {}
    for c in cells:
        column = columns.setdefault((c.setting, c.dataset, c.metric), [])
        if c.ours is not None and c.paper is not None:
            column.append((c.policy, c.ours, c.paper))
    out = []
    for (s, d, m), both in columns.items():
        ranked = m not in EXPECTED or EXPECTED[m].ranked
        ours, theirs = [o for _, o, _ in both], [t for _, _, t in both]
        out.append(
            Agreement(
                s,
                d,
                m,
                tuple(policy for policy, _, _ in both),
                spearman(ours, theirs) if ranked else None,
                float(np.mean([abs(o - t) for o, t in zip(ours, theirs, strict=True)])) if both else None,
                ranked,
            )
        )
    return tuple(out)


def score_weights(setting: str) -> dict[str, float]:
    """``setting``'s score weights (:data:`robobpp.scoring.scores.WEIGHTS`) without :data:`SCORE_LEFT_OUT`,
    renormalised to sum to 1, so the score compared keeps the paper's proportions between the other metrics."""
    kept = {k: w for k, w in WEIGHTS[setting].items() if k not in SCORE_LEFT_OUT}
    total = sum(kept.values())
    return {k: w / total for k, w in kept.items()}


def weighted_min_max(columns: Mapping[str, Sequence[float]], weights: Mapping[str, float]) -> list[float]:
    """The paper's score of each method from its figures (``columns``: per metric, one figure per method):
    each metric min–max normalised over the methods in its better direction, then weighted.

    The normalisation is the leaderboard's (:func:`robobpp.scoring.scores.normalize`): a constant column
    (every method equal) normalises to 0 for every method, so it contributes 0 and moves no method against
    another; the weights are not renormalised around it (every method loses that weight alike, so no order
    moves)."""
    return weighted_sum({metric: normalize(list(columns[metric]), metric) for metric in weights}, weights)


def compare_scores(
    ours: Mapping[Key, float | None], theirs: Mapping[Key, float] | None = None
) -> tuple[ScoreComparison, ...]:
    """Per (setting, dataset) of ``ours``: the paper's weighted min–max score (:func:`weighted_min_max`) over
    the compared methods, once from our figures and once from the paper's figures of the same methods and
    metrics, with the Spearman of the two columns.

    Decision Time and PPH are left out (:data:`SCORE_LEFT_OUT`), the other weights renormalised
    (:func:`score_weights`). The compared methods are those with a finite figure, ours and the paper's, for
    every scored metric; a method missing one is left out of both columns, since a min–max over other methods
    would move every score. ``theirs``: the paper's figures (default: :func:`robobpp.paper.paper_tables`).
    The paper's own ``score`` is not this: it is normalised over its twelve methods and weighs Decision Time.
    """
    if theirs is None:
        theirs = {(v.setting, v.dataset, v.method, v.metric): v.value for v in paper_tables().values}
    boards = sorted(
        {(s, d) for s, d, _, _ in ours},
        key=lambda sd: (place_in_order(sd[0], SETTINGS), place_in_order(sd[1], DATASETS)),
    )
    out = []
    for setting, dataset in boards:
        weights = score_weights(setting)
        methods = _ordered({p for s, d, p, _ in ours if (s, d) == (setting, dataset)}, PAPER_BASELINES)
        both = [
            p
            for p in methods
            if all(
                _is_finite(ours.get((setting, dataset, p, m)))
                and _is_finite(theirs.get((setting, dataset, p, m)))
                for m in weights
            )
        ]
        if not both:
            continue
        mine = weighted_min_max(
            {m: [_value(ours, setting, dataset, p, m) for p in both] for m in weights}, weights
        )
        paper = weighted_min_max(
            {m: [_value(theirs, setting, dataset, p, m) for p in both] for m in weights}, weights
        )
        out.append(
            ScoreComparison(
                setting, dataset, weights, tuple(both), tuple(mine), tuple(paper), spearman(mine, paper)
            )
        )
    return tuple(out)


def _is_finite(value: float | None) -> bool:
    return value is not None and math.isfinite(value)


def _value(
    figures: Mapping[Key, float | None], setting: str, dataset: str, policy: str, metric: str
) -> float:
    value = figures[(setting, dataset, policy, metric)]
    assert value is not None  # compare_scores keeps only methods with every figure
    return float(value)


def _fmt(metric: str, value: float | None, signed: bool = False) -> str:
    if value is None:
        return "–"
    if metric == "pph":
        return f"{value:+.0f}" if signed else f"{value:.0f}"
    return f"{value:+.3f}" if signed else f"{value:.3f}"


def label(metric: str) -> str:
    return METRIC_BY_KEY[metric].label if metric in METRIC_BY_KEY else metric.upper()


#: What the renderers show where a Spearman would be for a metric whose ranking is not compared.
NOT_COMPARED = "not compared"
#: The mark of a paper-reported row (a method robobpp does not run: the paper's figures only).
PAPER_REPORTED = "paper-reported"
#: The heading of the score comparison (:func:`compare_scores`).
SCORE_TITLE = "Score (Decision Time left out)"


def spearman_text(agreement: Agreement | None) -> str:
    """A column's Spearman as the tables print it: two decimals, "–" when undefined, :data:`NOT_COMPARED` for
    a metric whose ranking is not compared."""
    if agreement is not None and not agreement.ranked:
        return NOT_COMPARED
    return "–" if agreement is None or agreement.spearman is None else f"{agreement.spearman:.2f}"


def policy_title(comparison: Comparison, policy: str, titles: Mapping[str, str]) -> str:
    """A row's method as the CLI prints it, marked when its figures are the paper's alone."""
    title = titles.get(policy, policy)
    return f"{title} ({PAPER_REPORTED})" if comparison.paper_only(policy) else title


def markdown(comparison: Comparison, titles: Mapping[str, str] | None = None) -> str:
    """One Markdown table per setting and metric: policies down (the paper-reported ones last), per dataset
    paper | ours | diff across, then Spearman and mean |diff| per dataset, then why the metric's figures are
    expected to differ with its docs link; after a setting's metrics, its score comparison."""
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
                out.append(f"| {policy_title(comparison, p, titles)} | " + " | ".join(row) + " |")
            spearmans = [spearman_text(comparison.agreement_of(s, d, m)) for d in datasets]
            diffs = [_fmt(m, a.mean_abs_diff if a else None) for a in _agreements(comparison, s, m)]
            for name, texts in (("Spearman", spearmans), ("mean abs diff", diffs)):
                row = [cell for t in texts for cell in ("", t, "")]  # under each dataset's "ours"
                out.append(f"| **{name}** | " + " | ".join(row) + " |")
            if m in EXPECTED:
                out.append(f"\n{EXPECTED[m].why} ([{EXPECTED[m].doc}]({EXPECTED[m].doc}))")
            out.append("")
        out += _markdown_scores(comparison, s, titles)
    return "\n".join(out)


def _agreements(comparison: Comparison, setting: str, metric: str) -> list[Agreement | None]:
    return [comparison.agreement_of(setting, d, metric) for d in comparison.datasets(setting)]


def _markdown_scores(comparison: Comparison, setting: str, titles: Mapping[str, str]) -> list[str]:
    """``setting``'s score comparison as a Markdown table: per dataset ours | from the paper's figures."""
    scored = [c for c in comparison.scores if c.setting == setting]
    if not scored:
        return []
    out = [f"**{setting.capitalize()} Pack · {SCORE_TITLE}**\n"]
    out.append(
        "| policy | " + " | ".join(f"{c.dataset} ours | {c.dataset} paper metrics" for c in scored) + " |"
    )
    out.append("|---|" + "---:|" * (2 * len(scored)))
    for p in _ordered({p for c in scored for p in c.policies}, PAPER_BASELINES):
        row = []
        for c in scored:
            both = c.of(p)
            row += [f"{both[0]:.3f}", f"{both[1]:.3f}"] if both else ["–", "–"]
        out.append(f"| {titles.get(p, p)} | " + " | ".join(row) + " |")
    texts = ["–" if c.spearman is None else f"{c.spearman:.2f}" for c in scored]
    out.append("| **Spearman** | " + " | ".join(cell for t in texts for cell in ("", t)) + " |")
    out.append(
        "\nThe paper's weighted min–max score over the methods compared here, from our figures and from the "
        "paper's figures of the same methods, without Decision Time (its hardware) and with the other weights "
        "renormalised."
    )
    out.append("")
    return out


__all__ = [
    "EXPECTED",
    "NOT_COMPARED",
    "PAPER_ONLY",
    "PAPER_REPORTED",
    "SCORE_LEFT_OUT",
    "SCORE_TITLE",
    "Agreement",
    "Cell",
    "Comparison",
    "Expectation",
    "Key",
    "ScoreComparison",
    "compare",
    "compare_scores",
    "compared_metrics",
    "figures_from_results",
    "markdown",
    "pph",
    "ranks",
    "run_baselines",
    "score_weights",
    "spearman",
    "spearman_text",
    "weighted_min_max",
    "with_derived",
]
