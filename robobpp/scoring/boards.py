"""Boards and the overall grid from stored runs: who is ranked, scores with intervals, each participant's best.

Pure functions of plain dicts (no database), so the server, the pages and the tests build boards alike.

Honest entries (docs/benchmark.md, "Who is ranked"): an entry is ranked on a board only when it is
*valid* (its submission finished without failure and at most ``stats.POLICY_FAILURE_SHARE`` of its episodes
ended in a policy failure) and *complete* (it ran every group the board's other entries ran). Failed and
partial entries are listed apart, without rank, and never enter a normalisation, so their arrival moves
no other entry's score. In the overall grid, the Mean ranks only submissions ranked on every board.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robobpp.scoring import stats
from robobpp.scoring.metrics import metrics_for
from robobpp.scoring.scores import (
    ANCHORS_VERSION,
    RANKED_BY,
    WEIGHTS,
    BoardScores,
    competition_ranks,
    score_board,
)

#: Resamples kept per board for the overall grid's Mean interval (of the board's ``stats.RESAMPLES``).
GRID_RESAMPLES = 250


def participant_key(row: Mapping[str, Any]) -> str:
    """Whose entry this is, for "each participant's best": each baseline counts as its own participant."""
    return f"baseline:{row['name']}" if row.get("baseline") else f"participant:{row['participant']}"


def classify_row(row: Mapping[str, Any], groups: int) -> tuple[str, str]:
    """A candidate run's status on a board of ``groups`` groups (``ranked``, ``failed``, ``partial``) and why."""
    extras = row.get("extras") or {}
    episodes = int(extras.get("episodes") or row.get("episodes_total") or 0)
    failures = stats.policy_failure_count(extras.get("terminations"))
    if stats.run_failed(extras.get("terminations"), episodes):
        share = f"{100 * stats.POLICY_FAILURE_SHARE:.0f} %"
        return "failed", f"{failures} of {episodes} episodes ended in a policy failure (more than {share})"
    if row.get("submission_status") == "failed":
        return "failed", "the submission failed (some episodes could not be evaluated)"
    if episodes < groups:
        return "partial", f"ran {episodes} of the board's {groups} groups"
    return "ranked", ""


def public_fields(row: Mapping[str, Any]) -> dict[str, Any]:
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
    unranked: list[dict[str, Any]]
    submitted: dict[str, int]


def classify(rows: Sequence[Mapping[str, Any]]) -> Classified:
    """Who is ranked on a board (module docstring) from its candidate runs."""
    counts = [int((r.get("extras") or {}).get("episodes") or r.get("episodes_total") or 0) for r in rows]
    valid = [
        n
        for r, n in zip(rows, counts, strict=True)
        if not stats.run_failed((r.get("extras") or {}).get("terminations"), n)
    ]
    groups = max(valid, default=0)
    # How many entries each participant has on this board: the best of many runs of a stochastic policy is
    # an optimistic figure, so its count is shown beside it (docs/benchmark.md, "Who is ranked").
    submitted: dict[str, int] = {}
    for row in rows:
        submitted[participant_key(row)] = submitted.get(participant_key(row), 0) + 1
    ranked_rows, unranked = [], []
    for row in rows:
        status, reason = classify_row(row, groups)
        if status == "ranked":
            ranked_rows.append(row)
        else:
            unranked.append(
                {
                    **public_fields(row),
                    "status": status,
                    "reason": reason,
                    "entries_submitted": submitted[participant_key(row)],
                }
            )
    return Classified(groups, ranked_rows, unranked, submitted)


def build_board(rows: Sequence[Mapping[str, Any]], dataset: str, setting: str, track: str) -> dict[str, Any]:
    """One board from its candidate runs (``submission_id``, ``name``, ``participant``, ``baseline``,
    ``submission_status``, ``episodes_total``, ``metrics``, ``extras``, ``figures``, ``completed_at``).

    ``entries`` are the ranked ones, best first; ``unranked`` the failed and partial ones. Keys starting
    with ``_`` are for the grid and never served.
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
) -> dict[str, Any]:
    """The board dict from its ranked entries' scores (``scores`` follows ``sorted_out.ranked``; its
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
    entries: list[dict[str, Any]],
    unranked: list[dict[str, Any]],
    samples: np.ndarray,
    stable_samples: np.ndarray,
    best_samples: Callable[[list[int]], np.ndarray],
) -> dict[str, Any]:
    """The board dict from its ranked entries (input order, ``_column`` = position) and unranked ones."""
    _mark_best(entries, best_samples)
    order = sorted(range(len(entries)), key=lambda i: (entries[i]["rank"], entries[i]["submission_id"]))
    unranked = sorted(unranked, key=lambda e: (e["status"], e["submission_id"]))
    best = [
        {**e, "rank": e["best_rank"], "rank_low": e["best_rank_low"], "rank_high": e["best_rank_high"]}
        for e in entries
        if e["best"]
    ]
    best.sort(key=lambda e: (e["rank"], e["submission_id"]))
    return board_dict(
        dataset, setting, track, groups, [entries[i] for i in order], unranked, best, samples, stable_samples
    )


def board_dict(
    dataset: str,
    setting: str,
    track: str,
    groups: int,
    entries: list[dict[str, Any]],
    unranked: list[dict[str, Any]],
    best: list[dict[str, Any]],
    samples: np.ndarray,
    stable_samples: np.ndarray,
    by_column: np.ndarray | None = None,
) -> dict[str, Any]:
    """The board dict from its entries in rank order, unranked ones and best entries, both sorted.
    ``by_column``: the entries' scores and stable scores by ``_column`` (2 × entries), when at hand."""
    if by_column is None:
        n = len(entries)
        at = np.fromiter((e["_column"] for e in entries), dtype=np.intp, count=n)
        by_column = np.zeros((2, n))
        by_column[0, at] = np.fromiter((e["score"] for e in entries), dtype=np.float64, count=n)
        by_column[1, at] = np.fromiter((e["stable"] for e in entries), dtype=np.float64, count=n)
    return {
        "dataset": dataset,
        "setting": setting,
        "track": track,
        "metrics": [m.key for m in metrics_for(setting)],
        "weights": WEIGHTS[setting],
        "ranked_by": RANKED_BY,
        "anchors": ANCHORS_VERSION,
        "groups": groups,
        "resamples": stats.RESAMPLES,
        "confidence": stats.CONFIDENCE,
        "entries": entries,
        "unranked": unranked,
        "_best": best,  # the default view, ready to page
        "_index": {e["submission_id"]: k for k, e in enumerate(entries)},  # position in "entries"
        # the grid's resamples, a row per entry (by ``_column``: the grid gathers its rows' entries, and rows
        # of a C-ordered matrix are contiguous); copies: a slice would keep the full resample arrays alive
        "_samples": np.ascontiguousarray(samples[:GRID_RESAMPLES].T),
        "_stable_samples": np.ascontiguousarray(stable_samples[:GRID_RESAMPLES].T),
        "_by_column": by_column,  # for the grid's means
    }


def _mark_best(
    entries: list[dict[str, Any]], samples: Callable[[list[int]], np.ndarray], score: str = "score"
) -> None:
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


def find_entry(board: Mapping[str, Any], submission_id: int) -> Mapping[str, Any] | None:
    """A submission's ranked entry on a board, or None (a dictionary lookup on a board built here)."""
    entries = board.get("entries") or []
    index = board.get("_index")
    if index is None:
        return next((e for e in entries if e.get("submission_id") == submission_id), None)
    i = index.get(submission_id)
    return entries[i] if i is not None else None


def board_view(
    board: Mapping[str, Any],
    view: str = "best",
    limit: int = 50,
    offset: int = 0,
    submission_id: int | None = None,
) -> dict[str, Any]:
    """One page of a board as served: ``best`` (each participant's best entry, ranked among them) or
    ``all`` entries; ``submission_id`` narrows to one submission (ranked or not)."""
    entries: Sequence[Mapping[str, Any]] = board["_best"] if view == "best" else board["entries"]
    unranked: Sequence[Mapping[str, Any]] = board["unranked"]
    if submission_id is not None:
        found = find_entry(board, submission_id)
        entries = [found] if found is not None else []
        unranked = [e for e in unranked if e["submission_id"] == submission_id]
    head = {k: v for k, v in board.items() if not k.startswith("_") and k not in ("entries", "unranked")}
    return {
        **head,
        "view": view,
        "total": len(entries),
        "limit": limit,
        "offset": offset,
        "entries": [_served(e) for e in entries[offset : offset + limit]],
        "unranked_total": len(unranked),
        "unranked": [dict(e) for e in unranked[:limit]],
    }


def _served(entry: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in entry.items() if not k.startswith("_") and not k.startswith("best_")}


#: A grid row's own figures (its cells aside): the mean of its board scores and its stable score, with intervals.
GRID_ROW_FIGURES = ("mean", "mean_low", "mean_high", "stable", "stable_low", "stable_high")


def build_grid(
    boards: Mapping[str, Mapping[str, Any]],
    datasets: Sequence[str],
    settings: Sequence[str],
    track: str,
    *,
    rank_intervals: Mapping[int, tuple[int, int]] | None = None,
    cells: dict[str, dict[int, tuple[Any, int, dict[str, Any]]]] | None = None,
) -> dict[str, Any]:
    """The overall grid: a cell per board a submission is ranked on; the Mean (with interval and rank
    interval) only for submissions ranked on every board. ``boards`` maps ``setting/dataset`` to a board.

    ``rank_intervals``: the rows' rank intervals of the all-rows view by submission id, as last computed,
    instead of computing them (a row missing there has none yet); None: computed now. ``cells``: the cells
    of the last grid by board and submission id, reused for an entry whose ``_base`` (the board engine's:
    the same object while its content stays) and rank did not move; updated here."""
    keys = [f"{s}/{d}" for s in settings for d in datasets]
    rows: dict[int, dict[str, Any]] = {}

    def row_for(e: Mapping[str, Any]) -> dict[str, Any]:
        row = rows[e["submission_id"]] = {  # built once per submission, not once per board
            "submission_id": e["submission_id"],
            "name": e["name"],
            "participant": e["participant"],
            "baseline": e["baseline"],
            "cells": {},
            "unranked": {},
            "_columns": {},
            "_bases": {},  # each cell's board entry's ``_base`` (the board engine's), for the grid's own
        }
        return row

    for key in keys:
        known = None if cells is None else cells.setdefault(key, {})
        for e in boards[key]["entries"]:  # 90,000 cells at 10,000 submissions: kept lean
            sid = e["submission_id"]
            row = rows.get(sid) or row_for(e)
            base = e.get("_base")
            if known is not None and base is not None:
                hit = known.get(sid)
                if hit is not None and hit[0] is base and hit[1] == e["rank"]:
                    row["cells"][key] = hit[2]
                    row["_columns"][key] = e["_column"]
                    row["_bases"][key] = base
                    continue
            cell = row["cells"][key] = {
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
            row["_bases"][key] = base
            if known is not None and base is not None:
                known[sid] = (base, e["rank"], cell)
        for e in boards[key]["unranked"]:
            (rows.get(e["submission_id"]) or row_for(e))["unranked"][key] = e["status"]
    complete = [r for r in rows.values() if len(r["cells"]) == len(keys) and keys]
    _grid_means(complete, boards, keys, rank_intervals)
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
    best = [
        {**r, "rank": r["best_rank"], "rank_low": r["best_rank_low"], "rank_high": r["best_rank_high"]}
        for r in complete
        if r["best"]
    ]
    best.sort(key=lambda r: (r["rank"], r["submission_id"]))
    ranked = {participant_key(r) for r in best}
    return {
        "datasets": list(datasets),
        "settings": list(settings),
        "track": track,
        "boards": len(keys),
        "ranked_by": RANKED_BY,
        "rows": complete,
        "apart": apart,
        "_best": best,
        "_best_apart": [r for r in apart if participant_key(r) not in ranked],
    }


def _grid_means(
    rows: list[dict[str, Any]],
    boards: Mapping[str, Mapping[str, Any]],
    keys: Sequence[str],
    known: Mapping[int, tuple[int, int]] | None = None,
) -> None:
    """Mean over boards with interval, rank and rank interval; then each participant's best row."""
    if not rows:
        return
    n = len(rows)
    rel = np.zeros((n, GRID_RESAMPLES), dtype=np.float64)  # a row per grid row: its samples contiguous
    stab = np.zeros_like(rel)
    score_sum = np.zeros(n)
    stable_sum = np.zeros(n)
    for key in keys:
        board = boards[key]
        cols = np.fromiter((r["_columns"][key] for r in rows), dtype=np.intp, count=n)
        samples, stable = board["_samples"], board["_stable_samples"]
        rel[:, : samples.shape[1]] += samples[cols]
        stab[:, : stable.shape[1]] += stable[cols]
        by_column = board["_by_column"]
        # summed board by board in the order of ``keys``: the same additions as a sum over each row's cells
        score_sum += by_column[0, cols]
        stable_sum += by_column[1, cols]
    rel /= len(keys)
    stab /= len(keys)
    means = [round(x, 12) for x in (score_sum / len(keys)).tolist()]
    stables = (stable_sum / len(keys)).tolist()
    ranks = competition_ranks(means)
    # the mean samples are rounded to 12 decimals (ties must tie); rounding is monotonic, so the interval
    # rounds the order statistics it picks instead of every sample (the same numbers, a 20 MB pass less)
    lo, hi = stats.interval(rel.T, decimals=12)
    slo, shi = stats.interval(stab.T)
    if known is None:
        rlo, rhi = stats.rank_interval(stats.rank_samples(np.round(rel.T, 12)))
        rank_ci: list[tuple[int, int] | None] = [(int(a), int(b)) for a, b in zip(rlo, rhi, strict=True)]
    else:
        rank_ci = [known.get(r["submission_id"]) for r in rows]
    # the samples are float32 (memory of a 10,000-entry cache): 6 decimals is their precision
    lo, hi, slo, shi = (np.round(a, 6) for a in (lo, hi, slo, shi))
    for i, r in enumerate(rows):
        row_rank_ci = rank_ci[i]
        r.update(
            status="ranked",
            boards=len(keys),
            mean=means[i],
            mean_low=float(lo[i]),
            mean_high=float(hi[i]),
            stable=stables[i],
            stable_low=float(slo[i]),
            stable_high=float(shi[i]),
            rank=ranks[i],
            rank_low=None if row_rank_ci is None else row_rank_ci[0],
            rank_high=None if row_rank_ci is None else row_rank_ci[1],
        )
    _mark_best(rows, lambda chosen: np.round(rel[chosen].T, 12), score="mean")


def grid_view(
    grid: Mapping[str, Any], view: str = "best", limit: int = 50, offset: int = 0
) -> dict[str, Any]:
    """One page of the grid: each participant's best complete submission (ranked among them) or all rows."""
    rows: list[Mapping[str, Any]] = grid["_best"] if view == "best" else grid["rows"]
    apart: list[Mapping[str, Any]] = grid["_best_apart"] if view == "best" else grid["apart"]
    head = {k: v for k, v in grid.items() if k not in ("rows", "apart") and not k.startswith("_")}
    return {
        **head,
        "view": view,
        "total": len(rows),
        "limit": limit,
        "offset": offset,
        "rows": [_served(r) for r in rows[offset : offset + limit]],
        "apart_total": len(apart),
        "apart": [_served(r) for r in apart[:limit]],
    }
