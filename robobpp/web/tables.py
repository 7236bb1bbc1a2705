"""Table models for the leaderboard pages, shaped from the server's query results (no second scoring).

The server's ``robobpp.db.queries`` ranks and scores; this module only decides what each cell shows:
column headers with their better-direction arrows, which cells are a column's top four, sort keys for
the sortable tables. Pure functions of plain dicts, so they are tested without a server.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from robobpp.metrics import METRIC_BY_KEY, metrics_for

#: How many of a column's best entries are highlighted (the paper highlights its top methods).
TOP = 4


@dataclass(frozen=True, slots=True)
class Column:
    key: str
    label: str
    better: str  # "up" | "down" | ""
    unit: str
    title: str

    @property
    def arrow(self) -> str:
        return {"up": "↑", "down": "↓"}.get(self.better, "")


def metric_columns(setting: str) -> list[Column]:
    cols = [
        Column(m.key, m.label, m.better, m.unit,
               f"{m.label}: {'higher' if m.better == 'up' else 'lower'} is better" + (f" ({m.unit})" if m.unit else ""))
        for m in metrics_for(setting)
    ]  # fmt: skip
    return cols


def dense_top(values: Sequence[float | None], better: str, top: int = TOP) -> list[int | None]:
    """Place (1..top) of each value among the distinct best values of a column, None past the top.

    Ties share a place; missing values never get one.
    """
    present = sorted({v for v in values if _finite(v)}, reverse=(better == "up"))
    best = present[:top]
    return [best.index(v) + 1 if _finite(v) and v in best else None for v in values]


def _finite(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def board_table(board: Mapping[str, Any]) -> dict[str, Any]:
    """Rows and columns of one leaderboard page from ``queries.leaderboard(...)``'s result."""
    setting = board["setting"]
    columns = metric_columns(setting)
    entries = list(board.get("entries", []))
    places = {
        c.key: dense_top([(e.get("metrics") or {}).get(c.key) for e in entries], c.better) for c in columns
    }
    score_places = dense_top([e.get("score") for e in entries], "up")
    rows = []
    for i, e in enumerate(entries):
        metrics = e.get("metrics") or {}
        extras = e.get("extras") or {}
        rows.append({
            "rank": e.get("rank"),
            "score": e.get("score"),
            "score_place": score_places[i],
            "submission_id": e.get("submission_id"),
            "name": e.get("name", ""),
            "participant": e.get("participant", ""),
            "baseline": bool(e.get("baseline")),
            "cells": [{"key": c.key, "value": metrics.get(c.key), "place": places[c.key][i],
                       "normalized": (e.get("normalized") or {}).get(c.key)} for c in columns],
            "pph": extras.get("pph"),
            "boxes_placed": extras.get("boxes_placed_mean"),
            "episodes": extras.get("episodes"),
        })  # fmt: skip
    return {"columns": columns, "rows": rows, "has_pph": setting == "execution"}


def grid_table(grid: Mapping[str, Any]) -> dict[str, Any]:
    """The overall 3 × 3 grid from ``queries.overall_grid(...)``: one column per (setting, dataset)."""
    settings = list(grid.get("settings", []))
    datasets = list(grid.get("datasets", []))
    keys = [f"{s}/{d}" for s in settings for d in datasets]
    rows = list(grid.get("rows", []))
    places = {
        k: dense_top([(r.get("cells") or {}).get(k, {}).get("score") for r in rows], "up") for k in keys
    }
    out = []
    for i, r in enumerate(rows):
        cells = []
        for k in keys:
            cell = (r.get("cells") or {}).get(k)
            cells.append({"key": k, "score": cell.get("score") if cell else None,
                          "rank": cell.get("rank") if cell else None, "place": places[k][i]})  # fmt: skip
        scores = [c["score"] for c in cells if c["score"] is not None]
        out.append({
            "submission_id": r.get("submission_id"), "name": r.get("name", ""),
            "participant": r.get("participant", ""), "baseline": bool(r.get("baseline")), "cells": cells,
            "mean": sum(scores) / len(scores) if scores else None, "boards": len(scores),
        })  # fmt: skip
    return {"settings": settings, "datasets": datasets, "keys": keys, "rows": out}


def radar_groups(runs: Sequence[Mapping[str, Any]], boards: Mapping[tuple[str, str], Mapping[str, Any]],
                 submission_id: int) -> list[dict[str, Any]]:  # fmt: skip
    """Normalised metrics (0..1, higher = better, as the board's scoring computed them), one radar per setting
    (settings measure different metrics), one series per dataset of that setting."""
    groups: dict[str, dict[str, Any]] = {}
    for run in runs:
        board = boards.get((run["dataset"], run["setting"]))
        entry = next(
            (e for e in (board or {}).get("entries", []) if e.get("submission_id") == submission_id), None
        )
        if entry is None:
            continue
        keys = [m.key for m in metrics_for(run["setting"])]
        group = groups.setdefault(run["setting"], {"setting": run["setting"], "series": [], "single": True,
                                                   "labels": [METRIC_BY_KEY[k].label for k in keys]})  # fmt: skip
        normalized = entry.get("normalized") or {}
        group["single"] = group["single"] and len(board.get("entries", [])) < 2
        group["series"].append({
            "label": f"{run['dataset']} (rank {entry.get('rank')} of {len(board.get('entries', []))})",
            "values": [round(float(normalized.get(k, 0.0)), 4) for k in keys],
        })  # fmt: skip
    return list(groups.values())


def histogram(values: Sequence[float], bins: int = 10, lo: float = 0.0, hi: float = 1.0) -> dict[str, list]:
    """Counts of values in equal bins over [lo, hi] (the last bin closed), with readable bin labels."""
    width = (hi - lo) / bins
    counts = [0] * bins
    for v in values:
        if not _finite(v):
            continue
        i = min(bins - 1, max(0, int((v - lo) / width)))
        counts[i] += 1
    labels = [f"{100 * (lo + i * width):.0f}–{100 * (lo + (i + 1) * width):.0f}%" for i in range(bins)]
    return {"labels": labels, "counts": counts}
