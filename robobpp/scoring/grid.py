"""The overall grid kept between updates, from the board engine's arrays.

:func:`robobpp.scoring.boards.build_grid` builds the grid from boards' ranked entries, a dict per cell: at
10,000 submissions 90,000 cells per grid, rebuilt on every update, most of them only because an arriving
entry moved their rank. :class:`GridMatrix` builds the same grid from each board's
:class:`~robobpp.scoring.boards.RankedView`: which submissions are ranked on every board, their columns and
cell ranks are array operations, the Mean is :func:`~robobpp.scoring.boards.grid_figures` (the same
arithmetic), and a row's dict without ranks (its ``_base``, what is published) is built again only when one
of its cells' board rows (their serials) or its own figures moved. The rows with their ranks are built on
first use (:class:`~robobpp.scoring.boards.LazyRows`); the best rows and the rows apart, a few hundred, at
once.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from robobpp.scoring.boards import (
    GRID_ROW_FIGURES,
    GridFigures,
    LazyRows,
    RankedView,
    best_of_participants,
    grid_figures,
    new_grid_row,
    participant_key,
    top_values,
)
from robobpp.scoring.scores import RANKED_BY

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


def _cell(base: Mapping[str, Any]) -> dict[str, Any]:
    """A cell from its board entry's row without ranks (so its ``rank`` is None)."""
    cell = {k: base[k] for k in _CELL_FIGURES}
    cell["pph"] = (base.get("extras") or {}).get("pph")
    return cell


class GridMatrix:
    """One overall grid (of a track and protocol) kept between updates (module docstring)."""

    def __init__(self, datasets: Sequence[str], settings: Sequence[str], track: str) -> None:
        self.datasets, self.settings, self.track = list(datasets), list(settings), track
        self.keys = [f"{s}/{d}" for s in settings for d in datasets]
        k = len(self.keys)
        #: The complete rows of the last grid (ids ascending), their cells' serials and own figures.
        self._sids = np.zeros(0, dtype=np.int64)
        self._serials = np.zeros((0, k), dtype=np.int64)
        self._figures = np.zeros((0, 9))
        #: Each complete row without its ranks, by submission id; each board's cells likewise.
        self._bases: dict[int, dict[str, Any]] = {}
        self._cells: list[dict[int, tuple[int, dict[str, Any]]]] = [{} for _ in range(k)]
        #: Each submission's participant key (what "each participant's best" groups by).
        self._who: dict[int, str] = {}
        #: The all-rows rank intervals as last computed (ids ascending, low, high).
        self._known: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def grid(self, boards: Mapping[str, Mapping[str, Any]], *, rank_intervals: bool) -> dict[str, Any]:
        """The grid of ``boards`` (``setting/dataset`` -> a board engine's board): as ``build_grid`` makes it,
        with every row's rank interval computed (``rank_intervals``) or as last computed."""
        views: list[RankedView] = [boards[key]["_ranked"] for key in self.keys]
        complete = np.zeros(0, dtype=np.int64)
        if views:
            complete = views[0].ids_by_column
            for v in views[1:]:
                complete = np.intersect1d(complete, v.ids_by_column, assume_unique=True)
        n, k = len(complete), len(self.keys)
        cols = np.empty((n, k), dtype=np.intp)
        serials = np.empty((n, k), dtype=np.int64)
        cell_ranks = np.empty((n, k), dtype=np.int64)
        for j, v in enumerate(views):
            cols[:, j] = np.searchsorted(v.ids_by_column, complete)
            serials[:, j] = v.serials[cols[:, j]]
            cell_ranks[:, j] = v.rank_by_column[cols[:, j]]
        sids = complete.tolist()
        for i, sid in enumerate(sids):
            if sid not in self._who:
                self._who[sid] = participant_key(views[0].bases[cols[i, 0]])
        tops: dict[str, dict[str, list[float]]] = {"best": {}, "all": {}}
        if n:
            rows, best, view = self._ranked(
                boards, views, complete, sids, cols, serials, cell_ranks, rank_intervals
            )
            chosen = np.isin(complete, [r["submission_id"] for r in best])
            for j, key in enumerate(self.keys):  # each view's column tops: what its pages highlight
                scores = boards[key]["_by_column"][0, cols[:, j]]
                tops["all"][key], tops["best"][key] = top_values(scores), top_values(scores[chosen])
        else:
            none = np.zeros(0, dtype=np.int64)
            rows, best, view = LazyRows(list), [], RankedView(none, none, none, none, [], none, cell_ranks)
            self._sids, self._serials, self._figures, self._bases = none, serials, np.zeros((0, 9)), {}
            tops = {v: {key: [] for key in self.keys} for v in ("best", "all")}
        apart = self._apart(boards, views, complete)
        ranked = {participant_key(r) for r in best}
        return {
            "datasets": self.datasets,
            "settings": self.settings,
            "track": self.track,
            "boards": k,
            "ranked_by": RANKED_BY,
            "rows": rows,
            "apart": apart,
            "_best": best,
            "_best_apart": [r for r in apart if participant_key(r) not in ranked],
            "_ranked": view,
            "_tops": tops,
        }

    def _ranked(
        self,
        boards: Mapping[str, Mapping[str, Any]],
        views: list[RankedView],
        complete: np.ndarray,
        sids: list[int],
        cols: np.ndarray,
        serials: np.ndarray,
        cell_ranks: np.ndarray,
        rank_intervals: bool,
    ) -> tuple[LazyRows, list[dict[str, Any]], RankedView]:
        """The complete rows: their Mean, best rows, rows without ranks (built again only where they moved)."""
        n = len(sids)
        f = grid_figures(boards, self.keys, cols, rank_intervals=rank_intervals)
        ranks = np.asarray(f.ranks, dtype=np.int64)
        if f.rank_low is not None and f.rank_high is not None:
            rank_low, rank_high = f.rank_low.astype(np.float64), f.rank_high.astype(np.float64)
            self._known = (complete, f.rank_low.astype(np.int64), f.rank_high.astype(np.int64))
        else:
            rank_low, rank_high = np.full(n, np.nan), np.full(n, np.nan)
            if self._known is not None and len(self._known[0]):
                known_ids, low, high = self._known
                at = np.minimum(np.searchsorted(known_ids, complete), len(known_ids) - 1)
                hit = known_ids[at] == complete
                rank_low[hit], rank_high[hit] = low[at[hit]], high[at[hit]]
        best_of = best_of_participants((self._who[s] for s in sids), complete, ranks, f.means, f.best_samples)
        is_best = np.zeros(n)
        is_best[list(best_of)] = 1.0
        figures = np.column_stack(
            [f.means, f.low, f.high, f.stables, f.stable_low, f.stable_high, rank_low, rank_high, is_best]
        )
        # a row is built again when a cell's board row or its own figures moved (its ranks aside)
        at = np.minimum(np.searchsorted(self._sids, complete), max(len(self._sids) - 1, 0))
        kept = np.zeros(n, dtype=bool)
        if len(self._sids):
            kept = self._sids[at] == complete
            kept &= np.all(self._serials[at] == serials, axis=1)
            same = (self._figures[at] == figures) | (np.isnan(self._figures[at]) & np.isnan(figures))
            kept &= np.all(same, axis=1)
        bases = self._bases
        for i in np.flatnonzero(~kept).tolist():
            bases[sids[i]] = self._base(views, sids[i], cols[i], serials[i], figures[i], f, i)
        self._bases = {sid: bases[sid] for sid in sids}
        if rank_intervals:  # a full computation: forget the cells of rows gone
            self._cells = [{sid: c[sid] for sid in sids if sid in c} for c in self._cells]
        self._sids, self._serials, self._figures = complete, serials, figures
        row_bases = [self._bases[sid] for sid in sids]
        order = np.lexsort((complete, ranks))  # rank order, ties by id
        view = RankedView(
            complete[order],
            ranks[order],
            complete,
            ranks,
            row_bases,
            np.zeros(0, np.int64),
            cell_ranks[order],
        )

        def listed(i: int) -> dict[str, Any]:
            """Row ``i`` as the all-rows view lists it (``build_grid``'s row, without ``_base``)."""
            base = row_bases[i]
            row = base | {
                "rank": int(ranks[i]),
                "cells": {
                    key: base["cells"][key] | {"rank": int(cell_ranks[i, j])}
                    for j, key in enumerate(self.keys)
                },
                "_columns": {key: int(cols[i, j]) for j, key in enumerate(self.keys)},
                "_bases": {key: views[j].bases[cols[i, j]] for j, key in enumerate(self.keys)},
            }
            b = best_of.get(i)
            if b is not None:
                row["best_rank"], row["best_rank_low"], row["best_rank_high"] = b
            return row

        in_order = order.tolist()
        rows = LazyRows(lambda: [listed(i) | {"_base": row_bases[i]} for i in in_order])
        best = [listed(i) | {"rank": b[0], "rank_low": b[1], "rank_high": b[2]} for i, b in best_of.items()]
        best.sort(key=lambda r: (r["rank"], r["submission_id"]))
        return rows, best, view

    def _base(
        self,
        views: list[RankedView],
        sid: int,
        cols: np.ndarray,
        serials: np.ndarray,
        figures: np.ndarray,
        f: GridFigures,
        i: int,
    ) -> dict[str, Any]:
        """A complete row without its ranks (``build_grid``'s row as the publisher stores it)."""
        cells = {}
        for j, key in enumerate(self.keys):
            known = self._cells[j].get(sid)
            if known is None or known[0] != serials[j]:
                known = self._cells[j][sid] = (int(serials[j]), _cell(views[j].bases[cols[j]]))
            cells[key] = known[1]
        first = views[0].bases[cols[0]]
        rank_low, rank_high = figures[6], figures[7]
        return {
            "submission_id": sid,
            "name": first["name"],
            "participant": first["participant"],
            "baseline": first["baseline"],
            "cells": cells,
            "unranked": {},
            "status": "ranked",
            "boards": len(self.keys),
            "mean": f.means[i],
            "mean_low": float(f.low[i]),
            "mean_high": float(f.high[i]),
            "stable": f.stables[i],
            "stable_low": float(f.stable_low[i]),
            "stable_high": float(f.stable_high[i]),
            "rank": None,
            "rank_low": None if np.isnan(rank_low) else int(rank_low),
            "rank_high": None if np.isnan(rank_high) else int(rank_high),
            "best": bool(figures[8]),
        }

    def _apart(
        self, boards: Mapping[str, Mapping[str, Any]], views: list[RankedView], complete: np.ndarray
    ) -> list[dict[str, Any]]:
        """The rows of submissions not ranked on every board (``build_grid``'s, a few hundred)."""
        rows: dict[int, dict[str, Any]] = {}

        def row_for(e: Mapping[str, Any]) -> dict[str, Any]:
            row = rows.get(e["submission_id"])
            if row is None:
                row = rows[e["submission_id"]] = new_grid_row(e)
            return row

        for key, v in zip(self.keys, views, strict=True):
            apart = np.setdiff1d(v.ids_by_column, complete, assume_unique=True)
            columns = np.searchsorted(v.ids_by_column, apart)
            for c in sorted(columns.tolist(), key=lambda c: (v.rank_by_column[c], v.ids_by_column[c])):
                base = v.bases[c]
                row = row_for(base)
                row["cells"][key] = _cell(base) | {"rank": int(v.rank_by_column[c])}
                row["_columns"][key] = c
                row["_bases"][key] = base
            for e in boards[key]["unranked"]:
                row_for(e)["unranked"][key] = e["status"]
        out = list(rows.values())
        for r in out:
            r["status"] = "failed" if "failed" in r["unranked"].values() else "partial"
            r["boards"] = len(r["cells"])
            r.update(dict.fromkeys((*GRID_ROW_FIGURES, "rank", "rank_low", "rank_high")), best=False)
        out.sort(key=lambda r: (r["status"], -r["boards"], r["submission_id"]))
        return out
