"""Runs whose recorded metrics are odd (an integer, a boolean, infinity, a missing metric, a key the setting does
not have): the board engine scores them as the from-scratch computation does, and shows each entry's metrics
as recorded."""

from __future__ import annotations

import math
from typing import Any

from robobpp.boards.matrix import BoardMatrix
from robobpp.boards.ranking import build_board


def _run(sid: int, metrics: dict[str, Any]) -> dict[str, Any]:
    """A finished run without per-group figures: its point metrics count in every resample."""
    return {
        "submission_id": sid,
        "name": f"n{sid}",
        "participant": f"p{sid}",
        "baseline": False,
        "submission_status": "completed",
        "episodes_total": 3,
        "metrics": metrics,
        "extras": {"episodes": 3, "terminations": {"completed": 3}},
        "figures": None,
        "completed_at": None,
        "verification": None,
        "ids": None,
    }


def test_odd_metric_values_score_as_from_scratch_and_show_as_recorded() -> None:
    recorded = {
        1: {"space_utilization": 0.5, "occupancy": 0.8, "decision_time": 0.01},  # plain floats
        2: {"space_utilization": 1, "occupancy": 0.7, "decision_time": 0.02},  # an integer
        3: {"space_utilization": 0.6, "occupancy": math.inf, "decision_time": 0.03},  # not finite
        4: {"space_utilization": 0.4, "occupancy": 0.9, "decision_time": True},  # a boolean is no number
        5: {"space_utilization": 0.45, "occupancy": 0.85, "decision_time": 0.01, "extra": 1.0},
        6: {"space_utilization": 0.55, "occupancy": 0.75},  # a metric missing
    }
    runs = [_run(sid, m) for sid, m in recorded.items()]
    matrix = BoardMatrix("diverse", "math", "private", "closed", lambda sids: dict.fromkeys(sids))
    matrix.apply(runs, [], parts=dict.fromkeys(recorded))
    board = matrix.board(rank_intervals=True)
    reference = build_board(runs, "diverse", "math", "private")
    assert [e["submission_id"] for e in board.entries] == [e["submission_id"] for e in reference.entries]
    for mine, theirs in zip(board.entries, reference.entries, strict=True):
        sid = mine["submission_id"]
        assert (mine["score"], mine["rank"]) == (theirs["score"], theirs["rank"]), sid
        assert mine["normalized"] == theirs["normalized"], sid
        assert mine["metrics"] == recorded[sid] == theirs["metrics"], sid
    # the integer counts as its value, the boolean, infinity and the missing metric as missing: the run with
    # a whole 1 of space utilisation leads, and every missing value normalises to 0
    assert board.entries[0]["submission_id"] == 2
    by_id = {e["submission_id"]: e for e in board.entries}
    assert by_id[4]["normalized"]["decision_time"] == by_id[6]["normalized"]["decision_time"] == 0.0
    assert by_id[3]["normalized"]["occupancy"] == 0.0
