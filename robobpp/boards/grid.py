"""The overall grid kept between updates, from the board engine's boards.

:func:`robobpp.boards.ranking.build_grid` builds the grid from boards' ranked entries, a dict per cell: at
10,000 submissions 90,000 cells per grid, rebuilt on every update, most of them only because an arriving
entry moved their rank. :class:`GridMatrix` builds the same grid from each board's
:class:`~robobpp.boards.records.RankedView`: which submissions are ranked on every board, their columns and
cell ranks are array operations, and the Mean is :func:`~robobpp.boards.ranking.grid_figures` (the same
arithmetic) of sums of the boards' samples the grid keeps, one float64 matrix (rows × resamples). A row's
sums are computed again (from the boards' figures, :meth:`~robobpp.boards.matrix.BoardMatrix.grid_samples`)
only when one of its entries changed, and only the resamples a board renormalised otherwise. Rows are
built on demand; a row's serial changes whenever one of its cells' board rows or its own figures moved.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robobpp.boards.matrix import BoardMatrix, new_serials
from robobpp.boards.ranking import (
    GRID_RESAMPLES,
    GRID_ROW_FIGURES,
    best_apart,
    best_of_participants,
    grid_figures,
    new_grid_row,
    top_values,
)
from robobpp.boards.records import Board, Grid, LazyRows, RankedView, Row, Tops, empty_tops
from robobpp.scoring import stats

#: A cell's figures as its board entry shows them (``build_grid``'s cell, in its order; ``pph`` last).
_CELL_FIGURES = (
    "score",
    "score_low",
    "score_high",
    "rank",
    "rank_low",
    "rank_high",
    "stable",
    "stable_low",
    "stable_high",
)
#: A row's own figures as kept (its serial changes when one does): ``GRID_ROW_FIGURES``, rank interval, best.
_FIGURES = 9


def _cell(base: Mapping[str, Any]) -> dict[str, Any]:
    """A cell from its board entry's row without ranks (so its ``rank`` is None)."""
    cell = {k: base[k] for k in _CELL_FIGURES}
    cell["pph"] = (base.get("extras") or {}).get("pph")
    return cell


@dataclass(frozen=True, slots=True)
class _Rows:
    """The complete rows as one update left them: what their rows are built from, on demand."""

    keys: list[str]
    views: list[RankedView]
    sids: np.ndarray
    cols: np.ndarray
    figures: np.ndarray  # rows × _FIGURES (NaN: no rank interval)

    def row(self, i: int) -> Row:
        """Row ``i`` without its ranks (``build_grid``'s row as the publisher stores it)."""
        boards = [v.row(int(self.cols[i, j])) for j, v in enumerate(self.views)]
        f = self.figures[i].tolist()
        return {
            "submission_id": int(self.sids[i]),
            "name": boards[0]["name"],
            "participant": boards[0]["participant"],
            "baseline": boards[0]["baseline"],
            "cells": {key: _cell(b) for key, b in zip(self.keys, boards, strict=True)},
            "unranked": {},
            "status": "ranked",
            "boards": len(self.keys),
            "mean": f[0],
            "mean_low": f[1],
            "mean_high": f[2],
            "stable": f[3],
            "stable_low": f[4],
            "stable_high": f[5],
            "rank": None,
            "rank_low": None if np.isnan(f[6]) else int(f[6]),
            "rank_high": None if np.isnan(f[7]) else int(f[7]),
            "best": bool(f[8]),
        }


def stable_interval(sums: np.ndarray, boards: int) -> np.ndarray:
    """Rows' stable Mean intervals (rows × 2) from their sums of stable score samples over ``boards`` boards
    (rows × resamples), to the float32 samples' precision."""
    low, high = stats.interval((sums / boards).T)
    return np.column_stack([np.round(low, 6), np.round(high, 6)])


class GridSums:
    """A grid's sums of its boards' grid samples, gathered while a full computation makes its boards one after
    the other (each board's samples are at hand then, and dropped with the board's computation): where the
    grid would compute every board's samples of every row again (``GridMatrix._samples``).

    The sums are added board by board in the order of the grid's keys, as ``GridMatrix._samples`` adds them
    (float additions: the same order, the same bits); a board offered out of that order turns the sums off
    (the grid computes its own). Rows are the submissions ranked on every board so far (ids ascending). Once
    every board is added, the stable sums give way to the rows' stable intervals (what the grid keeps of them):
    a grid complete before the others frees its share of the peak."""

    def __init__(self, keys: Sequence[str]) -> None:
        self.keys = list(keys)
        self._next = 0  # the index in ``keys`` of the board to add next; -1: turned off
        self.ids = np.zeros(0, np.int64)
        self.rel = np.zeros((0, GRID_RESAMPLES))
        self.stable = np.zeros((0, GRID_RESAMPLES))

    def add(self, key: str, ids_by_column: np.ndarray, rel: np.ndarray, stable: np.ndarray) -> None:
        """Board ``key``'s grid samples (columns × resamples, ``BoardMatrix.take_grid_samples``) of the
        submissions ``ids_by_column`` (ascending)."""
        if self._next < 0 or self._next >= len(self.keys) or self.keys[self._next] != key:
            self._next = -1
            self.ids, self.rel, self.stable = self.ids[:0], self.rel[:0], self.stable[:0]
            return
        if self._next == 0:
            self.ids = np.asarray(ids_by_column, np.int64)
            self.rel = np.zeros((len(self.ids), rel.shape[1]))
            self.stable = np.zeros_like(self.rel)
        else:
            kept = np.isin(self.ids, ids_by_column, assume_unique=True)
            if not kept.all():
                self.ids, self.rel, self.stable = self.ids[kept], self.rel[kept], self.stable[kept]
        self._next += 1
        if len(self.ids) == len(ids_by_column):  # the same ids (a subset, both ascending): no gather (a copy)
            self.rel += rel
            self.stable += stable
        else:
            at = np.searchsorted(ids_by_column, self.ids)
            self.rel += rel[at]
            self.stable += stable[at]
        if self._next == len(self.keys):
            self.stable = stable_interval(self.stable, len(self.keys))

    def rows(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The rows of submissions ``ids``: their sums of relative score samples and their stable intervals
        (rows × 2), or None when some are not here (or not every board was added)."""
        if self._next != len(self.keys) or not len(self.ids):
            return None
        at = np.minimum(np.searchsorted(self.ids, ids), len(self.ids) - 1)
        if not np.array_equal(self.ids[at], ids):
            return None
        if len(at) == len(self.ids):  # every row, in order: no copy
            return self.rel, self.stable
        return self.rel[at], self.stable[at]


class GridMatrix:
    """One overall grid (of a track and loop) kept between updates (module docstring)."""

    def __init__(self, datasets: Sequence[str], settings: Sequence[str], track: str) -> None:
        self.datasets, self.settings, self.track = list(datasets), list(settings), track
        self.keys = [f"{s}/{d}" for s in settings for d in datasets]
        self._forget()

    def _forget(self) -> None:
        """No complete row known (a new grid, or one that has none)."""
        k = len(self.keys)
        #: The complete rows of the last grid (ids ascending), their cells' entry versions and serials,
        #: their sums of relative score samples, their stable intervals, their own figures and serials.
        self._sids = np.zeros(0, dtype=np.int64)
        self._versions = np.zeros((0, k), dtype=np.int64)
        self._cell_serials = np.zeros((0, k), dtype=np.int64)
        self._sums = np.zeros((0, GRID_RESAMPLES))
        self._stable_ci = np.zeros((0, 2))
        self._figures = np.zeros((0, _FIGURES))
        self._serials = np.zeros(0, dtype=np.int64)
        #: Per board: the board and its resample stamps as last summed (a resample stamped later is summed again).
        self._seen: list[tuple[BoardMatrix | None, np.ndarray]] = [(None, np.zeros(0, np.int64))] * k
        #: The all-rows rank intervals as last computed (ids ascending, low, high).
        self._known: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def grid(
        self,
        boards: Mapping[str, Board],
        matrices: Mapping[str, BoardMatrix],
        *,
        rank_intervals: bool,
        loop: str,
        lookahead: int,
        gathered: GridSums | None = None,
    ) -> Grid:
        """The grid of ``boards`` (``setting/dataset`` -> the board ``matrices[key]`` handed out last): as
        ``build_grid`` makes it, with every row's rank interval computed (``rank_intervals``) or as last
        computed. ``gathered``: its rows' sums as a full computation of the boards gathered them."""
        views = [_ranked(boards[key]) for key in self.keys]
        complete = np.zeros(0, dtype=np.int64)
        if views:
            complete = views[0].ids_by_column
            for v in views[1:]:
                complete = np.intersect1d(complete, v.ids_by_column, assume_unique=True)
        n, k = len(complete), len(self.keys)
        cols = np.empty((n, k), dtype=np.intp)
        serials = np.empty((n, k), dtype=np.int64)
        versions = np.empty((n, k), dtype=np.int64)
        cell_ranks = np.empty((n, k), dtype=np.int64)
        for j, (key, v) in enumerate(zip(self.keys, views, strict=True)):
            cols[:, j] = np.searchsorted(v.ids_by_column, complete)
            serials[:, j] = v.serials[cols[:, j]]
            versions[:, j] = matrices[key].versions()[cols[:, j]]
            cell_ranks[:, j] = v.rank_by_column[cols[:, j]]
        tops: Tops = {"best": {}, "all": {}}
        if n:
            rows, best, view = self._ranked(
                boards,
                matrices,
                views,
                complete,
                cols,
                serials,
                versions,
                cell_ranks,
                rank_intervals,
                gathered,
            )
            chosen = np.isin(complete, [r["submission_id"] for r in best])
            for j, key in enumerate(self.keys):  # each view's column tops: what its pages highlight
                scores = boards[key].grid_inputs().by_column[0, cols[:, j]]
                tops["all"][key], tops["best"][key] = top_values(scores), top_values(scores[chosen])
        else:
            none = np.zeros(0, dtype=np.int64)
            rows, best = LazyRows(list), []
            view = RankedView(none, none, none, none, none, _no_row, cell_ranks)
            self._forget()
            tops = empty_tops(self.keys)
        apart = self._apart(boards, views, complete)
        return Grid(
            self.datasets,
            self.settings,
            self.track,
            rows,
            apart,
            best,
            best_apart(best, apart),
            tops,
            loop,
            lookahead,
            ranked=view,
        )

    def _samples(
        self, matrices: Mapping[str, BoardMatrix], cols: np.ndarray, resamples: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rows' sums of relative and stable score samples over the boards, board by board in the order of
        ``keys`` (``boards.grid_sums``'s additions)."""
        width = GRID_RESAMPLES if resamples is None else len(resamples)
        rel = np.zeros((len(cols), width))
        stable = np.zeros_like(rel)
        for j, key in enumerate(self.keys):
            r, s = matrices[key].grid_samples(cols[:, j], resamples)
            rel += r
            stable += s
        return rel, stable

    def _ranked(
        self,
        boards: Mapping[str, Board],
        matrices: Mapping[str, BoardMatrix],
        views: list[RankedView],
        complete: np.ndarray,
        cols: np.ndarray,
        serials: np.ndarray,
        versions: np.ndarray,
        cell_ranks: np.ndarray,
        rank_intervals: bool,
        gathered: GridSums | None,
    ) -> tuple[LazyRows, list[Row], RankedView]:
        """The complete rows: their Mean, best rows, serials (new where a row moved; its ranks aside)."""
        n = len(complete)
        at = np.minimum(np.searchsorted(self._sids, complete), max(len(self._sids) - 1, 0))
        kept = np.zeros(n, dtype=bool)
        if len(self._sids):
            kept = (self._sids[at] == complete) & np.all(self._versions[at] == versions, axis=1)
        # the resamples some board renormalised since the grid last summed them
        moved = np.zeros(GRID_RESAMPLES, dtype=bool)
        for j, key in enumerate(self.keys):
            matrix, stamps = self._seen[j]
            now = matrices[key].resample_stamps
            moved |= np.ones_like(moved) if matrix is not matrices[key] else now > stamps
            self._seen[j] = (matrices[key], now.copy())
        sums = np.empty((n, GRID_RESAMPLES))
        stable_ci = np.empty((n, 2))
        sums[kept], stable_ci[kept] = self._sums[at[kept]], self._stable_ci[at[kept]]
        fresh = np.flatnonzero(~kept)
        if len(fresh):
            found = gathered.rows(complete[fresh]) if gathered is not None else None
            if found is None:
                rel, stable = self._samples(matrices, cols[fresh], None)
                found = rel, stable_interval(stable, len(self.keys))
            sums[fresh], stable_ci[fresh] = found
        again = np.flatnonzero(kept)
        if moved.any() and len(again):
            resamples = np.flatnonzero(moved)
            rel, _ = self._samples(matrices, cols[again], resamples)
            sums[np.ix_(again, resamples)] = rel
        f = grid_figures(
            boards,
            self.keys,
            cols,
            rank_intervals=rank_intervals,
            sums=(sums, np.zeros((n, 0))),
        )
        ranks = np.asarray(f.ranks, dtype=np.int64)
        if f.rank_low is not None and f.rank_high is not None:
            rank_low, rank_high = f.rank_low.astype(np.float64), f.rank_high.astype(np.float64)
            self._known = (complete, f.rank_low.astype(np.int64), f.rank_high.astype(np.int64))
        else:
            rank_low, rank_high = np.full(n, np.nan), np.full(n, np.nan)
            if self._known is not None and len(self._known[0]):
                known_ids, low, high = self._known
                where = np.minimum(np.searchsorted(known_ids, complete), len(known_ids) - 1)
                hit = known_ids[where] == complete
                rank_low[hit], rank_high[hit] = low[where[hit]], high[where[hit]]
        who = matrices[self.keys[0]].participants(cols[:, 0])
        best_of = best_of_participants(who, complete, ranks, f.means, f.best_samples)
        is_best = np.zeros(n)
        is_best[list(best_of)] = 1.0
        figures = np.column_stack(
            [f.means, f.low, f.high, f.stables, stable_ci, rank_low, rank_high, is_best]
        )
        # a row's serial changes when a cell's board row or its own figures moved (its ranks aside)
        same = np.zeros(n, dtype=bool)
        if len(self._sids):
            same = (self._sids[at] == complete) & np.all(self._cell_serials[at] == serials, axis=1)
            equal = (self._figures[at] == figures) | (np.isnan(self._figures[at]) & np.isnan(figures))
            same &= np.all(equal, axis=1)
        row_serials = np.where(same, self._serials[at] if len(self._sids) else 0, 0)
        row_serials[~same] = new_serials(int((~same).sum()))
        self._sids, self._versions, self._cell_serials = complete, versions, serials
        self._sums, self._stable_ci, self._figures, self._serials = sums, stable_ci, figures, row_serials
        built = _Rows(self.keys, views, complete, cols, figures)
        order = np.lexsort((complete, ranks))  # rank order, ties by id
        view = RankedView(
            complete[order], ranks[order], complete, ranks, row_serials, built.row, cell_ranks[order]
        )

        def listed(i: int) -> Row:
            """Row ``i`` as the all-rows view lists it (``build_grid``'s row)."""
            base = built.row(i)
            row = base | {
                "rank": int(ranks[i]),
                "cells": {
                    key: base["cells"][key] | {"rank": int(cell_ranks[i, j])}
                    for j, key in enumerate(self.keys)
                },
                "_columns": {key: int(cols[i, j]) for j, key in enumerate(self.keys)},
            }
            b = best_of.get(i)
            if b is not None:
                row["best_rank"], row["best_rank_low"], row["best_rank_high"] = b
            return row

        rows = LazyRows(lambda: [listed(i) | {"_base": built.row(i)} for i in order.tolist()])
        best = [listed(i) | {"rank": b[0], "rank_low": b[1], "rank_high": b[2]} for i, b in best_of.items()]
        best.sort(key=lambda r: (r["rank"], r["submission_id"]))
        return rows, best, view

    def _apart(self, boards: Mapping[str, Board], views: list[RankedView], complete: np.ndarray) -> list[Row]:
        """The rows of submissions not ranked on every board (``build_grid``'s, a few hundred)."""
        rows: dict[int, Row] = {}

        def row_for(e: Mapping[str, Any]) -> Row:
            row = rows.get(e["submission_id"])
            if row is None:
                row = rows[e["submission_id"]] = new_grid_row(e)
            return row

        for key, v in zip(self.keys, views, strict=True):
            apart = np.setdiff1d(v.ids_by_column, complete, assume_unique=True)
            columns = np.searchsorted(v.ids_by_column, apart)
            for c in sorted(columns.tolist(), key=lambda c: (v.rank_by_column[c], v.ids_by_column[c])):
                base = v.row(c)
                row = row_for(base)
                row["cells"][key] = _cell(base) | {"rank": int(v.rank_by_column[c])}
                row["_columns"][key] = c
            for e in boards[key].unranked:
                row_for(e)["unranked"][key] = e["status"]
        out = list(rows.values())
        for r in out:
            r["status"] = "failed" if "failed" in r["unranked"].values() else "partial"
            r["boards"] = len(r["cells"])
            r.update(dict.fromkeys((*GRID_ROW_FIGURES, "rank", "rank_low", "rank_high")), best=False)
        out.sort(key=lambda r: (r["status"], -r["boards"], r["submission_id"]))
        return out


def _no_row(column: int) -> Row:
    raise IndexError(column)


def _ranked(board: Board) -> RankedView:
    if board.ranked is None:
        raise ValueError(
            f"the {board.setting}/{board.dataset} board is not the board engine's (no ranked view)"
        )
    return board.ranked
