"""Table models for the leaderboard pages, shaped from the server's query results (no second scoring).

The server's ``robobpp.boards.ranking`` ranks and scores; this module only decides what each cell shows:
column headers with their better-direction arrows, intervals as text, which cells are a column's top
four, sort keys for the sortable tables, pagination. Pure functions of plain dicts, so they are tested without a server.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeGuard

from robobpp.paper import PAPER_GROUPS
from robobpp.scoring.metrics import METRIC_BY_KEY, metrics_for
from robobpp.web import fmt_metric

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
        Column(
            m.key,
            m.label,
            m.better,
            m.unit,
            f"{m.label}: {'higher' if m.better == 'up' else 'lower'} is better"
            + (f" ({m.unit})" if m.unit else ""),
        )
        for m in metrics_for(setting)
    ]
    return cols


def dense_top(values: Sequence[float | None], better: str, top: int = TOP) -> list[int | None]:
    """Place (1..top) of each value among the distinct best values of a column, None past the top.

    Ties share a place; missing values never get one.
    """
    present = sorted({v for v in values if _finite(v)}, reverse=(better == "up"))
    best = present[:top]
    return [best.index(v) + 1 if _finite(v) and v in best else None for v in values]


def places(
    values: Sequence[float | None], better: str, tops: Sequence[float] | None = None
) -> list[int | None]:
    """Each value's place among ``tops`` (the view's best distinct values of the column, best first: a page
    shows a slice of its view, so its own best values are not the column's), or among the values given when
    the view's are not known."""
    if tops is None:
        return dense_top(values, better)
    best = list(tops)
    return [best.index(v) + 1 if _finite(v) and v in best else None for v in values]


def _finite(v: Any) -> TypeGuard[float]:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


#: Rows per page of the board and grid pages.
PAGE_SIZE = 50


def pages(shown: Mapping[str, Any], page: int) -> dict[str, Any]:
    """Pagination of a board or grid view (``board_view``/``grid_view`` result) for the templates."""
    total, size = int(shown.get("total", 0)), int(shown.get("limit", PAGE_SIZE)) or PAGE_SIZE
    last = max(1, math.ceil(total / size))
    return {
        "page": page,
        "last": last,
        "total": total,
        "prev": page - 1 if page > 1 else None,
        "next": page + 1 if page < last else None,
    }


def span(low: Any, high: Any, digits: int = 3) -> str:
    """An interval as text ("0.412–0.488"); empty when unknown."""
    if not (_finite(low) and _finite(high)):
        return ""
    return f"{low:.{digits}f}–{high:.{digits}f}"


def metric_span(low: Any, high: Any, key: str) -> str:
    """A metric's interval in the unit its value is printed in ("45.5%–55.5%" under "50.5%"); empty when
    unknown."""
    if not (_finite(low) and _finite(high)):
        return ""
    return f"{fmt_metric(low, key)}–{fmt_metric(high, key)}"


def _bounds(interval: Sequence[float] | None) -> tuple[float | None, float | None]:
    """An interval's (low, high), (None, None) when unknown; a pair, or a list once read back from JSON."""
    if not interval:
        return None, None
    low, high = interval
    return low, high


def rank_span(rank: Any, low: Any, high: Any) -> str:
    """A rank with its interval: "3 (2–5)", or just "3" when the interval is that rank alone."""
    if rank is None:
        return "—"
    return str(rank) if low == high == rank or low is None else f"{rank} ({low}–{high})"


def standing(entry: Mapping[str, Any], ranked: int) -> dict[str, Any]:
    """A submission's ranked entry on one board as its own page shows it, in the board's formats: the rank
    with its rank interval (``rank_pending``: none yet, a large board between two full computations), the
    relative and the stable score with their intervals, and each metric's interval in its unit. ``ranked``:
    how many entries the board ranks."""
    return {
        "rank": entry.get("rank"),
        "of": ranked,
        "rank_text": rank_span(entry.get("rank"), entry.get("rank_low"), entry.get("rank_high")),
        "rank_pending": entry.get("rank_low") is None,
        "score": entry.get("score"),
        "score_ci": span(entry.get("score_low"), entry.get("score_high")),
        "stable": entry.get("stable"),
        "stable_ci": span(entry.get("stable_low"), entry.get("stable_high")),
        "metric_ci": {k: metric_span(*_bounds(v), k) for k, v in (entry.get("intervals") or {}).items()},
    }


def board_table(board: Mapping[str, Any]) -> dict[str, Any]:
    """Rows and columns of one leaderboard page from a ``board_view(...)`` result."""
    setting = board["setting"]
    columns = metric_columns(setting)
    entries = list(board.get("entries", []))
    tops = board.get("column_tops") or {}
    column_places = {
        c.key: places([(e.get("metrics") or {}).get(c.key) for e in entries], c.better, tops.get(c.key))
        for c in columns
    }
    score_places = places([e.get("score") for e in entries], "up", tops.get("score"))
    rows = []
    for i, e in enumerate(entries):
        metrics = e.get("metrics") or {}
        extras = e.get("extras") or {}
        intervals = e.get("intervals") or {}
        rows.append(
            {
                "rank": e.get("rank"),
                "rank_text": rank_span(e.get("rank"), e.get("rank_low"), e.get("rank_high")),
                # ranked, its interval not computed yet (an entry that arrived since the last full computation)
                "rank_pending": e.get("rank") is not None and e.get("rank_low") is None,
                "score": e.get("score"),
                "score_ci": span(e.get("score_low"), e.get("score_high")),
                "stable": e.get("stable"),
                "stable_ci": span(e.get("stable_low"), e.get("stable_high")),
                "score_place": score_places[i],
                "submission_id": e.get("submission_id"),
                "name": e.get("name", ""),
                "participant": e.get("participant", ""),
                "baseline": bool(e.get("baseline")),
                "verification": e.get("verification"),
                "entries_submitted": e.get("entries_submitted") or 1,
                "best": bool(e.get("best")),
                "cells": [
                    {
                        "key": c.key,
                        "value": metrics.get(c.key),
                        "place": column_places[c.key][i],
                        "ci": metric_span(*_bounds(intervals.get(c.key)), c.key),
                        "normalized": (e.get("normalized") or {}).get(c.key),
                    }
                    for c in columns
                ],
                "pph": extras.get("pph"),
                "boxes_placed": extras.get("boxes_placed_mean"),
                "episodes": extras.get("episodes"),
            }
        )
    apart = [
        {
            "submission_id": e.get("submission_id"),
            "name": e.get("name", ""),
            "participant": e.get("participant", ""),
            "baseline": bool(e.get("baseline")),
            "status": e.get("status"),
            "reason": e.get("reason", ""),
            "figures": [(e.get("metrics") or {}).get(c.key) for c in columns],
        }
        for e in board.get("unranked", [])
    ]
    return {
        "columns": columns,
        "rows": rows,
        "has_pph": setting == "execution",
        "apart": apart,
        "apart_total": board.get("unranked_total", len(apart)),
    }


def grid_table(grid: Mapping[str, Any]) -> dict[str, Any]:
    """The overall 3 × 3 grid from a ``grid_view(...)`` result: one column per (setting, dataset); the Mean
    and its rank only for the rows ranked on every board, the partial and failed rows apart."""
    settings = list(grid.get("settings", []))
    datasets = list(grid.get("datasets", []))
    keys = [f"{s}/{d}" for s in settings for d in datasets]
    rows = list(grid.get("rows", []))
    tops = grid.get("column_tops") or {}
    cell_places = {
        k: places([(r.get("cells") or {}).get(k, {}).get("score") for r in rows], "up", tops.get(k))
        for k in keys
    }

    def shaped(r: Mapping[str, Any], i: int | None) -> dict[str, Any]:
        cells = []
        for k in keys:
            cell = (r.get("cells") or {}).get(k)
            cells.append(
                {
                    "key": k,
                    "score": cell.get("score") if cell else None,
                    "rank": cell.get("rank") if cell else None,
                    "ci": span(cell.get("score_low"), cell.get("score_high")) if cell else "",
                    "rank_ci": rank_span(cell.get("rank"), cell.get("rank_low"), cell.get("rank_high"))
                    if cell
                    else "",
                    "unranked": (r.get("unranked") or {}).get(k),
                    "place": cell_places[k][i] if i is not None else None,
                }
            )
        return {
            "submission_id": r.get("submission_id"),
            "name": r.get("name", ""),
            "participant": r.get("participant", ""),
            "baseline": bool(r.get("baseline")),
            "cells": cells,
            "mean": r.get("mean"),
            "mean_ci": span(r.get("mean_low"), r.get("mean_high")),
            "stable": r.get("stable"),
            "stable_ci": span(r.get("stable_low"), r.get("stable_high")),
            "rank_text": rank_span(r.get("rank"), r.get("rank_low"), r.get("rank_high")),
            "status": r.get("status", "ranked"),
            "boards": r.get("boards", len([c for c in cells if c["score"] is not None])),
        }

    return {
        "settings": settings,
        "datasets": datasets,
        "keys": keys,
        "rows": [shaped(r, i) for i, r in enumerate(rows)],
        "apart": [shaped(r, None) for r in grid.get("apart", [])],
        "apart_total": grid.get("apart_total", 0),
    }


def radar_groups(
    runs: Sequence[Mapping[str, Any]], entries: Mapping[tuple[str, str], tuple[Mapping[str, Any], int]]
) -> list[dict[str, Any]]:
    """Normalised metrics (0..1, higher = better, as the board's scoring computed them), one radar per setting
    (settings measure different metrics), one series per dataset of that setting. ``entries``: the
    submission's ranked entry on each (dataset, setting) board and how many entries that board ranks."""
    groups: dict[str, dict[str, Any]] = {}
    for run in runs:
        found = entries.get((run["dataset"], run["setting"]))
        if found is None:
            continue
        entry, ranked = found
        keys = [m.key for m in metrics_for(run["setting"])]
        group = groups.setdefault(
            run["setting"],
            {
                "setting": run["setting"],
                "series": [],
                "single": True,
                "labels": [METRIC_BY_KEY[k].label for k in keys],
            },
        )
        normalized = entry.get("normalized") or {}
        group["single"] = group["single"] and ranked < 2
        group["series"].append(
            {
                "label": f"{run['dataset']} (rank {entry.get('rank')} of {ranked})",
                "values": [round(float(normalized.get(k, 0.0)), 4) for k in keys],
            }
        )
    return list(groups.values())


def histogram(
    values: Sequence[float], bins: int = 10, lo: float = 0.0, hi: float = 1.0
) -> dict[str, list[str] | list[int]]:
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


def _count_text(counts: Sequence[int]) -> str:
    """Groups behind a table's figures of ours: "2", or "2–30" when its figures differ."""
    if not counts:
        return "0"
    return str(counts[0]) if counts[0] == counts[-1] else f"{counts[0]}–{counts[-1]}"


def reproduction_tables(data: Mapping[str, Any], titles: Mapping[str, str]) -> list[dict[str, Any]]:
    """The Reproduction page from ``server.services.reproduction.reproduction``: one table per setting and
    metric (in the comparison's order: utilisation first), the paper's baselines down and then the paper-reported
    methods (the paper's figures only), per dataset the paper's figure, ours and the difference across, then
    Spearman ("not compared" for a metric whose ranking is not: ``ranked``) and mean |diff| per dataset, and
    why the metric's figures are expected to differ with its docs link. ``titles``: policy names as shown."""
    cells = list(data.get("cells") or [])
    agreement = {(a["setting"], a["dataset"], a["metric"]): a for a in data.get("agreement") or []}
    expected = data.get("expected") or {}
    groups = {(r["setting"], r["dataset"], r["policy"]): r["groups"] for r in data.get("runs") or []}
    out: list[dict[str, Any]] = []
    by_table: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for c in cells:
        by_table.setdefault((c["setting"], c["metric"]), []).append(c)
    for (setting, metric), group in by_table.items():
        datasets = list(dict.fromkeys(c["dataset"] for c in group))
        policies = list(dict.fromkeys(c["policy"] for c in group))
        found = {(c["dataset"], c["policy"]): c for c in group}
        rows = []
        for p in policies:
            row = []
            for d in datasets:
                c = found.get((d, p))
                row.append(
                    {
                        "paper": c and c["paper"],
                        "ours": c and c["ours"],
                        "diff": c and c["diff"],
                        "groups": groups.get((setting, d, p)),
                        "table": c and c["table"],
                    }
                )
            paper_only = any(c["policy"] == p and c.get("paper_only") for c in group)
            rows.append({"policy": p, "title": titles.get(p, p), "cells": row, "paper_only": paper_only})
        tables = [agreement.get((setting, d, metric)) or {} for d in datasets]
        metric_def = METRIC_BY_KEY.get(metric)
        counts = sorted({c["groups"] for r in rows for c in r["cells"] if c["groups"]})
        why = expected.get(metric) or {}
        out.append(
            {
                "setting": setting,
                "metric": metric,
                "label": metric_def.label if metric_def else metric.upper(),
                "better": metric_def.better if metric_def else "up",
                "datasets": datasets,
                "rows": rows,
                "spearman": [a.get("spearman") for a in tables],
                "mean_abs_diff": [a.get("mean_abs_diff") for a in tables],
                "ranked": bool(why.get("ranked", True)),
                "why": why.get("why", ""),
                "doc": why.get("doc", ""),
                "groups": _count_text(counts),
                "paper_groups": PAPER_GROUPS,
                # a figure over a few groups is far noisier than the paper's: say so beside the table, not on hover
                "few_groups": bool(counts) and counts[-1] * 3 <= PAPER_GROUPS,
            }
        )
    return out


def reproduction_scores(data: Mapping[str, Any], titles: Mapping[str, str]) -> list[dict[str, Any]]:
    """The Reproduction page's score comparisons (``data["scores"]``), one table per setting: the compared
    methods down, per dataset our score and the one from the paper's figures across, then the Spearman of the
    two per dataset. A method not compared on a dataset (a figure missing there) shows no score there."""
    by_setting: dict[str, list[Mapping[str, Any]]] = {}
    for score in data.get("scores") or []:
        by_setting.setdefault(score["setting"], []).append(score)
    out = []
    for setting, scores in by_setting.items():
        policies = list(dict.fromkeys(p for s in scores for p in s["policies"]))
        rows = []
        for p in policies:
            cells = []
            for s in scores:
                i = s["policies"].index(p) if p in s["policies"] else None
                cells.append(
                    {
                        "ours": s["ours"][i] if i is not None else None,
                        "paper": s["paper"][i] if i is not None else None,
                    }
                )
            rows.append({"policy": p, "title": titles.get(p, p), "cells": cells})
        out.append(
            {
                "setting": setting,
                "datasets": [s["dataset"] for s in scores],
                # the same per dataset: the setting's weights without Decision Time, renormalised
                "weights": " · ".join(
                    f"{METRIC_BY_KEY[k].label} {w:.2f}" for k, w in scores[0]["weights"].items()
                ),
                "rows": rows,
                "spearman": [s["spearman"] for s in scores],
            }
        )
    return out
