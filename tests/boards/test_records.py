"""Boards travel as typed records: the head a page repeats, what only the grid reads dropped when handed out,
a handed-out record never changed by the engine afterwards, and the store dispatching on the record."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from robobpp.boards.ranking import GRID_RESAMPLES, board_view, grid_sums
from robobpp.boards.records import Board, ForGrid, Grid, Published, as_board, as_grid, with_lookaheads
from robobpp.boards.store import parts_of
from robobpp.scoring.metrics import metrics_for
from robobpp.scoring.scores import WEIGHTS


def _entry(sid: int, rank: int, score: float) -> dict[str, object]:
    return {
        "submission_id": sid,
        "name": f"n{sid}",
        "participant": f"p{sid}",
        "baseline": False,
        "rank": rank,
        "score": score,
        "entries_submitted": 1,
        "_column": rank - 1,
    }


def _board(setting: str = "physics") -> Board:
    entries = [_entry(7, 1, 0.9), _entry(3, 2, 0.4)]
    unranked = [{"submission_id": 11, "status": "partial", "reason": "ran 2 of the board's 30 groups"}]
    grid = ForGrid(
        np.array([[0.9, 0.4], [0.8, 0.5]]),
        np.zeros((2, GRID_RESAMPLES), np.float32),
        np.zeros((2, GRID_RESAMPLES), np.float32),
    )
    return Board(
        "diverse", setting, "private", 30, entries, unranked, entries, {7: 0, 3: 1}, {}, for_grid=grid
    )


def test_a_board_head_carries_its_setting_rules_and_the_lookaheads_once_named() -> None:
    board = _board("physics")
    head = board.head()
    assert head["metrics"] == [m.key for m in metrics_for("physics")]
    assert head["weights"] == WEIGHTS["physics"] and head["groups"] == 30
    assert "lookaheads" not in head  # a board computed alone does not say which its track has
    named: dict[str, Published] = {"b": board}
    with_lookaheads(named, ["b"], [0, 10])
    assert named["b"].head()["lookaheads"] == [0, 10]
    # the record handed out before is a different object, and unchanged
    assert named["b"] is not board and board.lookaheads is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        board.groups = 3  # type: ignore[misc]
    page = board_view(board, "all")
    assert {k: page[k] for k in head} == head and [e["submission_id"] for e in page["entries"]] == [7, 3]
    assert all(not k.startswith("_") for e in page["entries"] for k in e)  # ``_column`` is never served


def test_a_served_board_has_no_grid_inputs_and_says_so_when_a_grid_asks() -> None:
    board = _board()
    served = board.served()
    assert served.for_grid is None and board.for_grid is not None
    assert served.entries is board.entries and served.best is board.best and served.index is board.index
    rel, _ = grid_sums({"physics/diverse": board}, ["physics/diverse"], np.array([[0], [1]]))
    assert rel.shape == (2, GRID_RESAMPLES)
    with pytest.raises(ValueError, match="handed out without its grid inputs"):
        grid_sums({"physics/diverse": served}, ["physics/diverse"], np.array([[0]]))


def test_the_store_and_the_narrowing_helpers_dispatch_on_the_record() -> None:
    board = _board()
    grid = Grid(["diverse"], ["physics"], "private", [], [], [], [], {"best": {}, "all": {}})
    stored = parts_of(board)
    assert stored.cells is None and stored.ids.tolist() == [7, 3]
    assert set(stored.chunks) == {"best:0", "unranked:0"}
    assert stored.head["head"] == board.head() and stored.head["unranked"] == [11]
    stored_grid = parts_of(grid)
    assert stored_grid.cells is not None and stored_grid.cells.shape == (0, 1)
    assert stored_grid.head["head"]["boards"] == 1
    assert as_board(board) is board and as_grid(grid) is grid
    with pytest.raises(TypeError, match="a grid where a board"):
        as_board(grid)
    with pytest.raises(TypeError, match="a board where a grid"):
        as_grid(board)
