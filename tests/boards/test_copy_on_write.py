"""A board's rows are built on demand from the columns as its update left them: the board holds those columns
(no copy) and copies them before it next writes them. Every kind of later update leaves the rows of a board
handed out before as they were, and a board's own columns stay writable."""

from __future__ import annotations

from datetime import datetime
from typing import Any

import numpy as np
import orjson

from robobpp.boards.matrix import BoardMatrix
from robobpp.boards.records import Board
from robobpp.scoring.entries import EntryPart, entry_part


def _run(sid: int, utilization: float, occupancy: float = 0.8) -> dict[str, Any]:
    return {
        "submission_id": sid,
        "name": f"policy {sid}",
        "participant": f"team {sid % 3}",
        "baseline": False,
        "submission_status": "completed",
        "episodes_total": 3,
        "metrics": {"space_utilization": utilization, "occupancy": occupancy, "decision_time": 0.01 * sid},
        "extras": {"episodes": 3, "terminations": {"completed": 3}},
        "figures": None,
        "completed_at": datetime(2026, 11, 29, 12, sid),
        "verification": None,
        "ids": None,
    }


def _rows(board: Board) -> bytes:
    """Every row of the board's all-entries view, built now from what it holds."""
    view = board.ranked
    assert view is not None
    return orjson.dumps([view.row(i) for i in range(len(view.ids_by_column))], option=orjson.OPT_NON_STR_KEYS)


def test_rows_handed_out_stay_as_they_were_through_every_kind_of_update() -> None:
    matrix = BoardMatrix("diverse", "math", "private", "closed", lambda sids: dict.fromkeys(sids))
    runs = {sid: _run(sid, 0.3 + 0.05 * sid) for sid in range(1, 9)}
    matrix.apply(list(runs.values()), [], parts=dict.fromkeys(runs))
    handed_out = [matrix.board(rank_intervals=True)]
    built = [_rows(handed_out[0])]
    updates = [
        ([_run(20, 0.55)], []),  # a middling entry: nobody else moves
        ([_run(21, 0.99, 0.99)], []),  # a new best: every other entry renormalised
        ([_run(3, 0.2, 0.1)], []),  # an entry whose metrics changed
        ([], [5]),  # a removal: the board renormalised in full
        ([_run(22, 0.1) | {"completed_at": "soon"}], [21]),  # an odd finish time, and the best leaves
    ]
    for upsert, gone in updates:
        matrix.apply(upsert, gone, parts={r["submission_id"]: None for r in upsert})
        handed_out.append(matrix.board())
        built.append(_rows(handed_out[-1]))
        # every board handed out so far still builds the rows it built when handed out
        assert [_rows(b) for b in handed_out] == built
    assert len(set(built)) == len(built), "each update changed what its board shows"
    ids = handed_out[-1].ranked.ids_by_column.tolist() if handed_out[-1].ranked is not None else []
    assert ids == [1, 2, 3, 4, 6, 7, 8, 20, 22]


def _measured(sid: int, rng: np.random.Generator, level: float) -> tuple[dict[str, Any], EntryPart]:
    """A run with per-group figures (so metric intervals from its part)."""
    values = {
        "space_utilization": (level + 0.1 * rng.random(6)).tolist(),
        "occupancy": (0.5 + 0.3 * rng.random(6)).tolist(),
        "decision_time": (0.01 * rng.random(6)).tolist(),
    }
    part = entry_part({"ids": list(range(6)), "values": values}, "math")
    metrics = {k: float(np.mean(v)) for k, v in values.items()}
    return _run(sid, 0.0) | {"metrics": metrics, "ids": part.ids.tobytes()}, part


def test_metric_intervals_shown_stay_as_they_were_when_parts_are_replaced() -> None:
    rng = np.random.default_rng(7)
    matrix = BoardMatrix("diverse", "math", "private", "closed", lambda sids: dict.fromkeys(sids))
    runs = {sid: _measured(sid, rng, 0.1 * sid) for sid in range(1, 7)}
    matrix.apply([r for r, _ in runs.values()], [], parts={s: p for s, (_, p) in runs.items()})
    handed_out = [matrix.board(rank_intervals=True)]
    built = [_rows(handed_out[0])]
    assert all(e["intervals"]["occupancy"] is not None for e in handed_out[0].entries)
    for upsert in ([2, 9], [4], [1, 2, 3, 5, 6]):  # new parts written over freed rows, and new rows
        again = {sid: _measured(sid, rng, 0.05 * sid) for sid in upsert}
        matrix.apply([r for r, _ in again.values()], [], parts={s: p for s, (_, p) in again.items()})
        handed_out.append(matrix.board())
        built.append(_rows(handed_out[-1]))
        assert [_rows(b) for b in handed_out] == built
    assert len(set(built)) == len(built)
