"""A board's positions by submission, read off its arrays, find each ranked entry and nothing else."""

from __future__ import annotations

import numpy as np
import pytest

from robobpp.boards.ranking import find_entry
from robobpp.boards.records import Board, Positions


def test_positions_follow_the_rank_order_of_the_columns() -> None:
    ids = np.array([3, 8, 11, 20, 41])  # columns: ascending submission ids
    ranks = np.array([2, 1, 5, 2, 4])
    order = np.lexsort((ids, ranks))  # rank order, ties by id: 8, 3, 20, 41, 11
    positions = Positions(ids, order)
    entries = [{"submission_id": int(ids[c])} for c in order]
    board = Board("diverse", "math", "private", 30, entries, [], [], positions, {})
    assert len(positions) == 5 and sorted(positions) == ids.tolist()
    for sid in ids.tolist():
        assert entries[positions[sid]]["submission_id"] == sid
        assert find_entry(board, sid) == {"submission_id": sid}
    for missing in (0, 4, 42):
        assert positions.get(missing) is None
        assert find_entry(board, missing) is None
        with pytest.raises(KeyError):
            positions[missing]
    assert len(Positions(np.zeros(0, np.int64), np.zeros(0, np.intp))) == 0
