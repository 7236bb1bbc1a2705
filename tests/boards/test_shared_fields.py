"""A submission's own fields (name, participant, verdict…) are kept once for all of a track's boards, and a
row handed out keeps what it showed when a verdict later changes."""

from __future__ import annotations

import math
from typing import Any

from robobpp.boards.matrix import BoardMatrix, SharedFields


def _run(sid: int, utilization: float, verification: str | None = None) -> dict[str, Any]:
    return {
        "submission_id": sid,
        "name": f"policy {sid}",
        "participant": f"team {sid % 2}",
        "baseline": sid == 1,
        "submission_status": "completed",
        "episodes_total": 3,
        "metrics": {"space_utilization": utilization, "occupancy": 0.8, "decision_time": 0.01},
        "extras": {"episodes": 3, "terminations": {"completed": 3}, "boxes_placed_mean": 10 * utilization},
        "figures": None,
        "completed_at": None,
        "verification": verification,
        "ids": None,
    }


def _board(shared: SharedFields, dataset: str) -> BoardMatrix:
    return BoardMatrix(dataset, "math", "private", "closed", lambda sids: dict.fromkeys(sids), shared=shared)


def test_boards_of_a_track_share_each_submissions_fields_and_rows_keep_theirs() -> None:
    shared = SharedFields()
    boards = {d: _board(shared, d) for d in ("repetitive", "diverse")}
    for k, board in enumerate(boards.values()):
        board.apply(
            [_run(sid, 0.1 * sid + 0.05 * k) for sid in (1, 2, 3)], [], parts=dict.fromkeys((1, 2, 3))
        )
    assert len(shared) == 3  # one per submission, not one per board and submission
    # the point: both boards hold the same object for each submission (one copy in memory)
    kept = [{id(x) for x in b._shared if x is not None} for b in boards.values()]
    assert len(kept[0]) == 3 and kept[0] == kept[1]
    packed = shared.packed(2, {"submission_id": 2, "name": "policy 2"})
    assert (
        shared.packed(2, {"submission_id": 2, "name": "policy 2"}) is packed
    )  # equal fields: the same object
    before = {d: b.board() for d, b in boards.items()}
    rows = {d: {e["submission_id"]: e for e in b.entries} for d, b in before.items()}
    for dataset in boards:
        assert rows[dataset][3]["name"] == "policy 3" and rows[dataset][3]["participant"] == "team 1"
        assert rows[dataset][1]["baseline"] is True and rows[dataset][2]["baseline"] is False
        assert rows[dataset][3]["verification"] is None
    # each board's own run fields stay its own
    assert math.isclose(rows["repetitive"][3]["extras"]["boxes_placed_mean"], 3.0)
    assert math.isclose(rows["diverse"][3]["extras"]["boxes_placed_mean"], 3.5)
    # a verdict arrives: the board updated shows it, the board handed out before does not change
    boards["diverse"].apply([_run(3, 0.35, "verified")], [], parts={3: None})
    after = {e["submission_id"]: e for e in boards["diverse"].board().entries}
    assert after[3]["verification"] == "verified"
    assert {e["submission_id"]: e for e in before["diverse"].entries}[3]["verification"] is None
    # submissions that left every board are forgotten
    shared.keep_only([1, 3])
    assert len(shared) == 2


def test_finish_times_come_back_as_they_were() -> None:
    """A board keeps finish times as arrays (wall time, zone), anything else beside them: every row shows its
    run's time as recorded — to the microsecond, with its zone, or none."""
    from datetime import UTC, datetime, timedelta, timezone
    from zoneinfo import ZoneInfo

    times: dict[int, Any] = {
        1: datetime(2026, 11, 29, 16, 20, 5, 123456),
        2: datetime(2026, 11, 29, 16, 20, 5, 123456, tzinfo=UTC),
        3: datetime(1999, 1, 1, 0, 0, 0, 1, tzinfo=timezone(timedelta(hours=-5))),
        4: None,
        5: "2026-11-29T16:20:05Z",
        6: datetime(2026, 10, 25, 1, 30, fold=1),  # the second 1:30 of a repeated hour
        7: datetime(2026, 7, 1, 12, 0, 0, 999999, tzinfo=ZoneInfo("Europe/Paris")),  # summer time
        8: datetime(2026, 1, 1, 12, 0, tzinfo=ZoneInfo("Europe/Paris")),
        9: datetime(1, 1, 1),  # the first and last a datetime can hold
        10: datetime(9999, 12, 31, 23, 59, 59, 999999, tzinfo=timezone(timedelta(hours=13, minutes=45))),
        11: datetime(1969, 12, 31, 23, 59, 59, 999999, tzinfo=timezone(timedelta(minutes=-30))),
    }
    board = _board(SharedFields(), "diverse")
    board.apply(
        [_run(sid, 0.1 * sid) | {"completed_at": at} for sid, at in times.items()],
        [],
        parts=dict.fromkeys(times),
    )
    first = board.board()
    shown = {e["submission_id"]: e["completed_at"] for e in first.entries}
    assert shown == times
    assert shown[1].tzinfo is None and shown[2].tzinfo is UTC and shown[3].utcoffset() == timedelta(hours=-5)
    assert shown[6].fold == 1
    for sid in (7, 8, 9, 10, 11):  # the same wall time and zone, not only the same instant
        assert (shown[sid].replace(tzinfo=None), shown[sid].tzinfo) == (
            times[sid].replace(tzinfo=None),
            times[sid].tzinfo,
        )
    # a run finishing again moves its own time only; the rows handed out before keep theirs
    board.apply([_run(2, 0.2) | {"completed_at": datetime(2027, 1, 1)}], [], parts={2: None})
    again = {e["submission_id"]: e["completed_at"] for e in board.board().entries}
    assert again == times | {2: datetime(2027, 1, 1)}
    assert {e["submission_id"]: e["completed_at"] for e in first.entries} == times


def test_a_run_set_again_unchanged_keeps_its_packed_fields_and_a_changed_one_gets_new() -> None:
    """A refresh sets every row again: an entry whose run fields pack the same keeps the object it had (made
    again among each board's transient rows, 30 MB of them at 10,000 submissions left the heap holed: the board
    worker held 426 MB after a refresh where its start left 390, the same live objects), and a row handed out
    before a change keeps showing the old fields."""
    board = _board(SharedFields(), "repetitive")
    runs = [_run(sid, 0.1 * sid) for sid in (1, 2, 3)]
    board.apply(runs, [], parts=dict.fromkeys((1, 2, 3)))
    before = list(board._public)
    shown = {e["submission_id"]: e for e in board.board().entries}
    changed = _run(2, 0.2) | {"extras": {"episodes": 3, "terminations": {"completed": 3}, "pph": 120.5}}
    board.apply([*(_run(sid, 0.1 * sid) for sid in (1, 3)), changed], [], parts=dict.fromkeys((1, 2, 3)))
    after = list(board._public)
    slot = {int(sid): k for k, sid in enumerate(board._c.sid[: len(after)].tolist())}
    assert after[slot[1]] is before[slot[1]] and after[slot[3]] is before[slot[3]]
    assert after[slot[2]] is not before[slot[2]]
    now = {e["submission_id"]: e for e in board.board().entries}
    assert now[2]["extras"]["pph"] == 120.5 and "pph" not in shown[2]["extras"]
    assert now[1]["extras"] == shown[1]["extras"]
