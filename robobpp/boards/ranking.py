"""Boards and the overall grid from stored runs: who is ranked, scores with intervals, each participant's best.

Pure functions of the runs' rows (no database) giving :class:`~robobpp.boards.records.Board` and
:class:`~robobpp.boards.records.Grid` records, so the engine's equality test, the CLI and the tests build boards
alike.

Honest entries (docs/benchmark.md, "Who is ranked"): an entry is ranked on a board only when it is
*valid* (its submission finished without failure and at most ``stats.POLICY_FAILURE_SHARE`` of its episodes
ended in a policy failure) and *complete* (it ran every group the board's other entries ran). Failed and
partial entries are listed apart, without rank, and never enter a normalisation, so their arrival moves
no other entry's score. In the overall grid, the Mean ranks only submissions ranked on every board.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robobpp.boards.records import Board, ForGrid, Grid, Row
from robobpp.scoring import stats
from robobpp.scoring.metrics import METRIC_BY_KEY, metrics_for
from robobpp.scoring.scores import BoardScores, competition_ranks, score_board

#: Resamples kept per board for the overall grid's Mean interval (of the board's ``stats.RESAMPLES``).
GRID_RESAMPLES = 250


#: How many distinct best values of each column a board's pages highlight.
COLUMN_TOP = 4


def top_values(values: Iterable[Any], better: str = "up", top: int = COLUMN_TOP) -> list[float]:
    """The ``top`` best distinct finite values of a column, best first: what a page of a view highlights
    (a page shows a slice of the view; its best values are not the column's)."""
    if isinstance(values, np.ndarray):  # the board engine's arrays
        return _top(values.astype(np.float64), better, top)
    column = np.array(
        [v if isinstance(v, int | float) and not isinstance(v, bool) else np.nan for v in values]
    )
    return _top(column, better, top)


def _top(column: np.ndarray, better: str, top: int = COLUMN_TOP) -> list[float]:
    distinct = np.unique(column[np.isfinite(column)])  # ascending
    best = distinct[::-1][:top] if better == "up" else distinct[:top]
    return [float(v) for v in best.tolist()]


def board_tops(scores: np.ndarray, metrics: np.ndarray, keys: Sequence[str]) -> dict[str, list[float]]:
    """A view's column tops: its entries' scores and metrics (entries × ``keys``, NaN where missing)."""
    tops = {"score": _top(np.asarray(scores, dtype=np.float64), "up")}
    for j, key in enumerate(keys):
        tops[key] = _top(metrics[:, j], METRIC_BY_KEY[key].better)
    return tops


def _metric_matrix(keys: Sequence[str], entries: Sequence[Mapping[str, Any]]) -> np.ndarray:
    rows = [[(e.get("metrics") or {}).get(k) for k in keys] for e in entries]
    out = np.array(
        [[v if isinstance(v, int | float) and not isinstance(v, bool) else np.nan for v in r] for r in rows],
        dtype=np.float64,
    )
    return out.reshape(len(entries), len(keys))


def participant_key(row: Mapping[str, Any]) -> str:
    """Whose entry this is, for "each participant's best": each baseline counts as its own participant."""
    return f"baseline:{row['name']}" if row.get("baseline") else f"participant:{row['participant']}"


def ranked_of(
    episodes: np.ndarray, policy_failed: np.ndarray, submission_failed: np.ndarray
) -> tuple[int, np.ndarray]:
    """Who is ranked on a board (module docstring), the one rule: the board's groups (the most episodes of
    a run that is not failed) and which runs are ranked — neither failed nor short of those groups."""
    groups = int(episodes[~policy_failed].max()) if (~policy_failed).any() else 0
    return groups, ~policy_failed & ~submission_failed & (episodes >= groups)


def status_reason(
    episodes: int, failures: int, policy_failed: bool, submission_failed: bool, groups: int
) -> tuple[str, str]:
    """A run's status on a board of ``groups`` groups (``ranked``, ``failed``, ``partial``) and why (what
    :func:`ranked_of` decided, said)."""
    if policy_failed:
        share = f"{100 * stats.POLICY_FAILURE_SHARE:.0f} %"
        return "failed", f"{failures} of {episodes} episodes ended in a policy failure (more than {share})"
    if submission_failed:
        return "failed", "the submission failed (some episodes could not be evaluated)"
    if episodes < groups:
        return "partial", f"ran {episodes} of the board's {groups} groups"
    return "ranked", ""


def _run_status(row: Mapping[str, Any]) -> tuple[int, int, bool, bool]:
    """A candidate run's episodes, policy failures, whether those fail it and whether its submission failed."""
    extras = row.get("extras") or {}
    episodes = int(extras.get("episodes") or row.get("episodes_total") or 0)
    terminations = extras.get("terminations")
    return (
        episodes,
        stats.policy_failure_count(terminations),
        stats.run_failed(terminations, episodes),
        row.get("submission_status") == "failed",
    )


def public_fields(row: Mapping[str, Any]) -> Row:
    """What a board shows of a candidate run's row."""
    keys = (
        "submission_id",
        "name",
        "participant",
        "baseline",
        "metrics",
        "extras",
        "completed_at",
        "verification",
    )
    return {k: row.get(k) for k in keys} | {
        "metrics": row.get("metrics") or {},
        "extras": row.get("extras") or {},
    }


@dataclass(frozen=True, slots=True)
class Classified:
    """A board's candidate runs sorted out: the ranked ones (in input order), the unranked ones as served,
    the board's group count and each participant's number of entries."""

    groups: int
    ranked: list[Mapping[str, Any]]
    unranked: list[Row]
    submitted: dict[str, int]


def classify(rows: Sequence[Mapping[str, Any]]) -> Classified:
    """Who is ranked on a board (module docstring) from its candidate runs."""
    status = [_run_status(r) for r in rows]
    groups, ranked = ranked_of(
        np.array([s[0] for s in status], dtype=np.int64),
        np.array([s[2] for s in status], dtype=bool),
        np.array([s[3] for s in status], dtype=bool),
    )
    # How many entries each participant has on this board: the best of many runs of a stochastic policy is
    # an optimistic figure, so its count is shown beside it (docs/benchmark.md, "Who is ranked").
    submitted: dict[str, int] = {}
    for row in rows:
        submitted[participant_key(row)] = submitted.get(participant_key(row), 0) + 1
    ranked_rows, unranked = [], []
    for row, is_ranked, (episodes, failures, policy_failed, submission_failed) in zip(
        rows, ranked.tolist(), status, strict=True
    ):
        if is_ranked:
            ranked_rows.append(row)
        else:
            why = status_reason(episodes, failures, policy_failed, submission_failed, groups)
            unranked.append(
                {
                    **public_fields(row),
                    "status": why[0],
                    "reason": why[1],
                    "entries_submitted": submitted[participant_key(row)],
                }
            )
    return Classified(groups, ranked_rows, unranked, submitted)


def build_board(rows: Sequence[Mapping[str, Any]], dataset: str, setting: str, track: str) -> Board:
    """One board from its candidate runs (``submission_id``, ``name``, ``participant``, ``baseline``,
    ``submission_status``, ``episodes_total``, ``metrics``, ``extras``, ``figures``, ``completed_at``).

    ``entries`` are the ranked ones, best first; ``unranked`` the failed and partial ones.
    """
    sorted_out = classify(rows)
    scores = score_board(sorted_out.ranked, setting)
    return assemble_board(
        dataset, setting, track, sorted_out, scores, lambda chosen: scores.samples[:, chosen]
    )


def assemble_board(
    dataset: str,
    setting: str,
    track: str,
    sorted_out: Classified,
    scores: BoardScores,
    best_samples: Callable[[list[int]], np.ndarray],
) -> Board:
    """The board from its ranked entries' scores (``scores`` follows ``sorted_out.ranked``; its
    ``samples`` need only the grid's first :data:`GRID_RESAMPLES` resamples; ``best_samples(columns)``: the
    relative score samples of those columns under every resample, for the best entries' rank intervals).
    A rank interval of None is one not computed yet (the all-entries view between two full computations)."""
    entries = []
    submitted = sorted_out.submitted
    for i, row in enumerate(sorted_out.ranked):
        s = scores.scored[i]
        rank_ci = scores.rank_ci[i]
        entries.append(
            {
                **public_fields(row),
                "rank": s.rank,
                "rank_low": None if rank_ci is None else rank_ci[0],
                "rank_high": None if rank_ci is None else rank_ci[1],
                "score": s.score,
                "score_low": scores.score_ci[i][0],
                "score_high": scores.score_ci[i][1],
                "stable": scores.stable[i],
                "stable_low": scores.stable_ci[i][0],
                "stable_high": scores.stable_ci[i][1],
                "normalized": s.normalized,
                "intervals": {k: list(v) if v else None for k, v in scores.metric_ci[i].items()},
                "entries_submitted": submitted[participant_key(row)],
                "_column": i,
            }
        )
    return finish_board(
        dataset,
        setting,
        track,
        sorted_out.groups,
        entries,
        sorted_out.unranked,
        scores.samples,
        scores.stable_samples,
        best_samples,
    )


def finish_board(
    dataset: str,
    setting: str,
    track: str,
    groups: int,
    entries: list[Row],
    unranked: list[Row],
    samples: np.ndarray,
    stable_samples: np.ndarray,
    best_samples: Callable[[list[int]], np.ndarray],
) -> Board:
    """The board from its ranked entries (input order, ``_column`` = position) and unranked ones; ``samples``,
    ``stable_samples``: the entries' relative and stable score samples (resamples × entries; the grid keeps
    its first :data:`GRID_RESAMPLES`)."""
    _mark_best(entries, best_samples)
    by_column = np.zeros((2, len(entries)))
    by_column[0] = [e["score"] for e in entries]
    by_column[1] = [e["stable"] for e in entries]
    order = sorted(range(len(entries)), key=lambda i: (entries[i]["rank"], entries[i]["submission_id"]))
    ranked = [entries[i] for i in order]
    unranked = sorted(unranked, key=lambda e: (e["status"], e["submission_id"]))
    best = _best_view(entries)
    keys = [m.key for m in metrics_for(setting)]
    tops = {
        view: board_tops(np.array([e["score"] for e in listed]), _metric_matrix(keys, listed), keys)
        for view, listed in (("best", best), ("all", ranked))
    }
    # the grid's resamples, a row per entry (by ``_column``: the grid gathers its rows' entries, and rows of a
    # C-ordered matrix are contiguous); copies: a slice would keep the full resample arrays alive
    for_grid = ForGrid(
        by_column,
        np.ascontiguousarray(samples[:GRID_RESAMPLES].T),
        np.ascontiguousarray(stable_samples[:GRID_RESAMPLES].T),
    )
    return Board(
        dataset,
        setting,
        track,
        groups,
        ranked,
        unranked,
        best,
        {e["submission_id"]: k for k, e in enumerate(ranked)},
        tops,
        for_grid=for_grid,
    )


def _mark_best(entries: list[Row], samples: Callable[[list[int]], np.ndarray], score: str = "score") -> None:
    """Flag each participant's best entry (a board's entry or a grid row, ranked by ``score``) and rank the
    best ones among themselves (with intervals; ``samples(columns)``: those entries' score samples)."""
    best: dict[str, int] = {}
    for i, e in enumerate(entries):
        key = participant_key(e)
        j = best.get(key)
        if j is None or (e["rank"], e["submission_id"]) < (entries[j]["rank"], entries[j]["submission_id"]):
            best[key] = i
    chosen = sorted(best.values())
    ranks = competition_ranks([entries[i][score] for i in chosen])
    no_ranks = np.zeros(0, dtype=np.int64)
    low, high = stats.rank_interval(stats.rank_samples(samples(chosen))) if chosen else (no_ranks, no_ranks)
    for e in entries:
        e["best"] = False
    for k, i in enumerate(chosen):
        entries[i].update(
            best=True, best_rank=ranks[k], best_rank_low=int(low[k]), best_rank_high=int(high[k])
        )


def best_of_participants(
    who: Iterable[str],
    ids: np.ndarray,
    ranks: np.ndarray,
    scores: Sequence[float],
    samples: Callable[[list[int]], np.ndarray],
) -> dict[int, tuple[int, int, int]]:
    """:func:`_mark_best` by arrays (the board engine's boards and grid): each participant's best position
    (the least rank, then id, of theirs) -> its rank among the best ones and its rank interval
    (``samples(positions)``: those positions' score samples, resamples × positions)."""
    codes: dict[str, int] = {}
    n = len(ids)
    code = np.fromiter((codes.setdefault(w, len(codes)) for w in who), dtype=np.int64, count=n)
    by = np.lexsort((ids, ranks, code))
    chosen = np.sort(by[np.r_[True, code[by][1:] != code[by][:-1]]] if n else by).tolist()
    if not chosen:
        return {}
    best_ranks = competition_ranks([scores[i] for i in chosen])
    low, high = stats.rank_interval(stats.rank_samples(samples(chosen)))
    return {i: (best_ranks[k], int(low[k]), int(high[k])) for k, i in enumerate(chosen)}


def find_entry(board: Board, submission_id: int) -> Row | None:
    """A submission's ranked entry on a board, or None."""
    i = board.index.get(submission_id)
    return board.entries[i] if i is not None else None


def board_view(
    board: Board,
    view: str = "best",
    limit: int = 50,
    offset: int = 0,
    submission_id: int | None = None,
) -> dict[str, Any]:
    """One page of a board as served: ``best`` (each participant's best entry, ranked among them) or
    ``all`` entries; ``submission_id`` narrows to one submission (ranked or not)."""
    entries: Sequence[Row] = board.best if view == "best" else board.entries
    unranked: Sequence[Row] = board.unranked
    if submission_id is not None:
        found = find_entry(board, submission_id)
        entries = [found] if found is not None else []
        unranked = [e for e in unranked if e["submission_id"] == submission_id]
    head, tops = board.head(), board.tops.get(view, {})
    return _page(head, tops, view, limit, offset, ("entries", entries), ("unranked", unranked), dict)


def served_fields(entry: Mapping[str, Any]) -> Row:
    """An entry or grid row as served: without what is kept for the engine, the grid and the best view."""
    return {k: v for k, v in entry.items() if not k.startswith("_") and not k.startswith("best_")}


def new_grid_row(entry: Mapping[str, Any]) -> Row:
    """A grid row of ``entry``'s submission before its cells are put in (``_columns``: each cell's column on
    its board)."""
    return {
        "submission_id": entry["submission_id"],
        "name": entry["name"],
        "participant": entry["participant"],
        "baseline": entry["baseline"],
        "cells": {},
        "unranked": {},
        "_columns": {},
    }


#: A grid row's own figures (its cells aside): the mean of its board scores and its stable score, with intervals.
GRID_ROW_FIGURES = ("mean", "mean_low", "mean_high", "stable", "stable_low", "stable_high")


def build_grid(
    boards: Mapping[str, Board],
    datasets: Sequence[str],
    settings: Sequence[str],
    track: str,
) -> Grid:
    """The overall grid: a cell per board a submission is ranked on; the Mean (with interval and rank
    interval) only for submissions ranked on every board. ``boards`` maps ``setting/dataset`` to a board.
    (The board engine keeps a grid between updates: :class:`robobpp.boards.grid.GridMatrix`, the same grid.)"""
    keys = [f"{s}/{d}" for s in settings for d in datasets]
    rows: dict[int, Row] = {}

    def row_for(e: Mapping[str, Any]) -> Row:
        row = rows[e["submission_id"]] = new_grid_row(e)  # built once per submission, not once per board
        return row

    for key in keys:
        for e in boards[key].entries:
            row = rows.get(e["submission_id"]) or row_for(e)
            row["cells"][key] = {
                "score": e["score"],
                "score_low": e["score_low"],
                "score_high": e["score_high"],
                "rank": e["rank"],
                "rank_low": e["rank_low"],
                "rank_high": e["rank_high"],
                "stable": e["stable"],
                "stable_low": e["stable_low"],
                "stable_high": e["stable_high"],
                "pph": (e.get("extras") or {}).get("pph"),
            }
            row["_columns"][key] = e["_column"]
        for e in boards[key].unranked:
            (rows.get(e["submission_id"]) or row_for(e))["unranked"][key] = e["status"]
    complete = [r for r in rows.values() if len(r["cells"]) == len(keys) and keys]
    _grid_means(complete, boards, keys)
    ranked_ids = {r["submission_id"] for r in complete}
    apart = []
    for r in rows.values():
        if r["submission_id"] not in ranked_ids:
            r["status"] = "failed" if "failed" in r["unranked"].values() else "partial"
            r["boards"] = len(r["cells"])
            r.update(dict.fromkeys((*GRID_ROW_FIGURES, "rank", "rank_low", "rank_high")), best=False)
            apart.append(r)
    complete.sort(key=lambda r: (r["rank"], r["submission_id"]))
    apart.sort(key=lambda r: (r["status"], -r["boards"], r["submission_id"]))
    best = _best_view(complete)
    tops = {
        view: {k: top_values(r["cells"][k]["score"] for r in listed) for k in keys}
        for view, listed in (("best", best), ("all", complete))
    }
    return Grid(list(datasets), list(settings), track, complete, apart, best, best_apart(best, apart), tops)


def _best_view(rows: Sequence[Row]) -> list[Row]:
    """The default view of ranked rows that :func:`_mark_best` marked: each participant's best, ranked among
    them (their ``best_rank`` and its interval as their rank), in rank order."""
    best = [
        {**r, "rank": r["best_rank"], "rank_low": r["best_rank_low"], "rank_high": r["best_rank_high"]}
        for r in rows
        if r["best"]
    ]
    best.sort(key=lambda r: (r["rank"], r["submission_id"]))
    return best


def best_apart(best: Sequence[Row], apart: Sequence[Row]) -> list[Row]:
    """The grid's rows apart that its default view lists: those of participants with no best ranked row."""
    ranked = {participant_key(r) for r in best}
    return [r for r in apart if participant_key(r) not in ranked]


@dataclass
class GridFigures:
    """The Mean of the grid's complete rows (in the order given) and what it is ranked by."""

    means: list[float]
    stables: list[float]
    ranks: list[int]
    #: the Mean's and the stable score's intervals (rounded to the float32 samples' precision)
    low: np.ndarray
    high: np.ndarray
    stable_low: np.ndarray
    stable_high: np.ndarray
    #: the Mean's samples, a row per grid row (for the best rows' rank intervals)
    samples: np.ndarray
    #: the rows' rank intervals of the all-rows view, when computed
    rank_low: np.ndarray | None = None
    rank_high: np.ndarray | None = None

    def best_samples(self, chosen: Sequence[int]) -> np.ndarray:
        return np.round(self.samples[list(chosen)].T, 12)


def grid_sums(
    boards: Mapping[str, Board], keys: Sequence[str], cols: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The sums over boards of the relative and stable score samples (float32 each, summed in float64 in
    the order of ``keys``) of rows whose cell on board ``keys[j]`` is column ``cols[i, j]`` of that board:
    (rows, :data:`GRID_RESAMPLES`) each."""
    n = cols.shape[0]
    rel = np.zeros((n, GRID_RESAMPLES), dtype=np.float64)  # a row per grid row: its samples contiguous
    stab = np.zeros_like(rel)
    for j, key in enumerate(keys):
        inputs = boards[key].grid_inputs()
        samples, stable = inputs.samples, inputs.stable_samples
        if samples is None or stable is None:
            raise ValueError(
                f"the {key} board carries no resamples for the grid (the engine's grid sums its own)"
            )
        at = cols[:, j]
        rel[:, : samples.shape[1]] += samples[at]
        stab[:, : stable.shape[1]] += stable[at]
    return rel, stab


def grid_figures(
    boards: Mapping[str, Board],
    keys: Sequence[str],
    cols: np.ndarray,
    *,
    rank_intervals: bool,
    sums: tuple[np.ndarray, np.ndarray] | None = None,
) -> GridFigures:
    """The Mean over boards of rows whose cell on board ``keys[j]`` is column ``cols[i, j]`` of that board:
    with interval, rank and (``rank_intervals``) the all-rows rank interval. ``sums``: the rows' sums of
    samples (:func:`grid_sums`) when at hand (the board engine's grid keeps them); not changed."""
    n = cols.shape[0]
    rel_sum, stab_sum = grid_sums(boards, keys, cols) if sums is None else sums
    score_sum = np.zeros(n)
    stable_sum = np.zeros(n)
    for j, key in enumerate(keys):
        by_column = boards[key].grid_inputs().by_column
        at = cols[:, j]
        # summed board by board in the order of ``keys``: the same additions as a sum over each row's cells
        score_sum += by_column[0, at]
        stable_sum += by_column[1, at]
    rel = rel_sum / len(keys)
    stab = stab_sum / len(keys)
    means = [round(x, 12) for x in (score_sum / len(keys)).tolist()]
    # the mean samples are rounded to 12 decimals (ties must tie); rounding is monotonic, so the interval
    # rounds the order statistics it picks instead of every sample (the same numbers, a 20 MB pass less)
    lo, hi = stats.interval(rel.T, decimals=12)
    # the engine's grid keeps its rows' stable intervals (an entry's stable samples are its own): no sums
    slo, shi = stats.interval(stab.T) if stab.shape[1] else (np.full(n, np.nan), np.full(n, np.nan))
    rlo = rhi = None
    if rank_intervals:
        rlo, rhi = stats.rank_interval(stats.rank_samples(np.round(rel.T, 12)))
    # the samples are float32 (memory of a 10,000-entry cache): 6 decimals is their precision
    lo, hi, slo, shi = (np.round(a, 6) for a in (lo, hi, slo, shi))
    return GridFigures(
        means, (stable_sum / len(keys)).tolist(), competition_ranks(means), lo, hi, slo, shi, rel, rlo, rhi
    )


def _grid_means(
    rows: list[Row],
    boards: Mapping[str, Board],
    keys: Sequence[str],
) -> None:
    """Mean over boards with interval, rank and rank interval; then each participant's best row."""
    if not rows:
        return
    cols = np.array([[r["_columns"][key] for key in keys] for r in rows], dtype=np.intp).reshape(
        len(rows), len(keys)
    )
    f = grid_figures(boards, keys, cols, rank_intervals=True)
    assert f.rank_low is not None and f.rank_high is not None
    for i, r in enumerate(rows):
        r.update(
            status="ranked",
            boards=len(keys),
            mean=f.means[i],
            mean_low=float(f.low[i]),
            mean_high=float(f.high[i]),
            stable=f.stables[i],
            stable_low=float(f.stable_low[i]),
            stable_high=float(f.stable_high[i]),
            rank=f.ranks[i],
            rank_low=int(f.rank_low[i]),
            rank_high=int(f.rank_high[i]),
        )
    _mark_best(rows, f.best_samples, score="mean")


def grid_view(grid: Grid, view: str = "best", limit: int = 50, offset: int = 0) -> dict[str, Any]:
    """One page of the grid: each participant's best complete submission (ranked among them) or all rows."""
    rows: Sequence[Row] = grid.best if view == "best" else grid.rows
    apart: Sequence[Row] = grid.best_apart if view == "best" else grid.apart
    head, tops = grid.head(), grid.tops.get(view, {})
    return _page(head, tops, view, limit, offset, ("rows", rows), ("apart", apart), served_fields)


def _page(
    head: dict[str, Any],
    tops: dict[str, list[float]],
    view: str,
    limit: int,
    offset: int,
    listed: tuple[str, Sequence[Mapping[str, Any]]],
    aside: tuple[str, Sequence[Mapping[str, Any]]],
    aside_row: Callable[[Mapping[str, Any]], dict[str, Any]],
) -> dict[str, Any]:
    """A page of a board or of the grid as served: its public fields, then ``offset``..``offset + limit`` of the
    ranked list and the first ``limit`` of those set aside (unranked entries, rows apart), with the counts and
    the view's column tops."""
    (listed_key, rows), (aside_key, apart) = listed, aside
    return {
        **head,
        "view": view,
        "total": len(rows),
        "limit": limit,
        "offset": offset,
        listed_key: [served_fields(r) for r in rows[offset : offset + limit]],
        f"{aside_key}_total": len(apart),
        aside_key: [aside_row(r) for r in apart[:limit]],
        "column_tops": tops,
    }
