"""Boards published as data, on SQLite and PostgreSQL: what readers page through equals the computed board,
a finished submission reaches every board route once the worker ran, readers keep the previous version while
the next is computed or when its worker dies, one worker computes, a restarted server serves the stored boards
without computing, two readers agree, and the process mode publishes on its own.

(Latencies are measured by bench/bench_server.py, never asserted here.)"""

from __future__ import annotations

import gc
import json
import threading
import time
import weakref
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from robobpp.boards import engine as board_engine
from robobpp.boards import reader as boards_module
from robobpp.boards import store as board_store
from robobpp.boards import store as store_module
from robobpp.boards import worker as board_worker_module
from robobpp.boards.engine import BoardEngine, compute_snapshot
from robobpp.boards.ranking import board_view, grid_view
from robobpp.boards.reader import BoardCache
from robobpp.boards.records import Board, Published, Row, as_board, as_grid
from robobpp.boards.store import board_key, to_json
from robobpp.boards.worker import BoardPublisher, BoardWorker, request_recompute
from robobpp.db.models import BoardPart, BoardPublication
from tests.server.conftest import submit_direct
from tests.server.test_scale import DATASETS, GROUPS, drain, make_app, operator_browser, submit

BOARD = "/api/v1/leaderboards/diverse/math?view=all"


def names(client: TestClient, path: str = BOARD) -> list[str]:
    return sorted(e["name"] for e in client.get(path).json()["entries"])


def publisher(app: Any, engine: Any = None, **kwargs: Any) -> BoardPublisher:
    runtime = app.state.runtime
    return BoardPublisher(
        runtime.read_session,
        runtime.session,
        DATASETS,
        ("math",),
        engine=engine,
        **kwargs,
    )


def reader(app: Any, **kwargs: Any) -> BoardCache:
    return BoardCache(app.state.runtime.read_session, datasets=DATASETS, settings=("math",), **kwargs)


def published(app: Any, track: str = "private") -> tuple[int, Any]:
    with app.state.runtime.read_session() as s:
        row = s.get(BoardPublication, track)
        return (row.version, row.source) if row is not None else (0, None)


def engine(app: Any) -> BoardEngine:
    return BoardEngine(app.state.runtime.read_session, DATASETS, ("math",))


class Gate:
    """A board engine that computes as the real one but waits for ``go`` first, counting its calls."""

    def __init__(self, inner: BoardEngine, fail: bool = False) -> None:
        self.inner, self.fail = inner, fail
        self.entered, self.go = threading.Event(), threading.Event()
        self.calls = 0

    def keys(self, track: str) -> list[Any]:
        return self.inner.keys(track)

    def update(self, track: str) -> Mapping[Any, Any]:
        self.calls += 1
        self.entered.set()
        assert self.go.wait(60)
        if self.fail:
            raise RuntimeError("the worker died mid-computation")
        return self.inner.update(track)


@pytest.fixture
def quiet_app(db_url: str, tmp_path: Path):
    """An app whose boards no worker publishes unless a test runs one, and whose readers never wait."""
    app = make_app(db_url, tmp_path, board_worker="off", board_wait_s=0)
    yield app
    app.state.runtime.dispose()


def test_pages_read_by_index_equal_the_computed_board(quiet_app, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every page a reader assembles from the stored chunks is the page ``board_view``/``grid_view`` cut from
    the whole board: views, offsets across chunk borders, one submission (ranked, unranked or absent)."""
    monkeypatch.setattr(store_module, "CHUNK", 2)  # several chunks with a handful of entries
    app = quiet_app
    ids = [
        submit(app, who, url)
        for who, url in (("a", "builtin:dbl"), ("b", "builtin:random"), ("a", "builtin:lsah"))
    ]
    ids.append(submit_direct(app, "c", "builtin:random", datasets=("diverse",), groups=GROUPS))  # apart
    drain(app)
    assert publisher(app).publish("private")
    cache = reader(app)
    with app.state.runtime.read_session() as s:
        snap = compute_snapshot(s, DATASETS, ("math",), "private")

    def plain(data: Any) -> Any:
        return json.loads(to_json(data))

    for dataset in DATASETS:
        board = as_board(snap[(dataset, "math")])
        for view in ("best", "all"):
            for limit, offset in ((50, 0), (1, 0), (3, 1), (2, 2), (5, 3), (1, 10)):
                got = cache.board_page(dataset, "math", "private", "closed", view, limit, offset)
                assert got == plain(board_view(board, view, limit, offset)), (dataset, view, limit, offset)
        for sid in (*ids, 10**6):
            got = cache.board_page(dataset, "math", "private", "closed", "all", 50, 0, sid)
            assert got == plain(board_view(board, "all", 50, 0, sid)), (dataset, sid)
    for view in ("best", "all"):
        for limit, offset in ((50, 0), (1, 1), (3, 0)):
            got = cache.grid_page("private", "closed", view, limit, offset)
            assert got == plain(grid_view(as_grid(snap["grid"]), view, limit, offset)), (view, limit, offset)
    assert len(as_grid(snap["grid"]).rows) == 3 and len(as_grid(snap["grid"]).apart) == 1


def test_a_finished_submission_appears_on_every_board_route_after_the_worker_runs(quiet_app) -> None:
    app = quiet_app
    worker = BoardWorker(publisher(app))
    sid = submit(app, "alice", "builtin:random", name="first-entry")
    drain(app)
    routes = [BOARD, "/api/v1/leaderboards?view=all", "/", "/boards/diverse/math?view=all"]
    with TestClient(app) as client:
        assert client.get(BOARD).status_code == 503  # nothing published yet: said so, never an empty board
        assert client.get("/").status_code == 503
        assert worker.run_once() == ["private", "public"]
        for path in routes:
            body = client.get(path).text
            assert "first-entry" in body and "second-entry" not in body, path
        second = submit(app, "bob", "builtin:dbl", name="second-entry")
        drain(app)
        for path in routes:  # not published yet: the previous version
            body = client.get(path).text
            assert "first-entry" in body and "second-entry" not in body, path
        assert worker.run_once() == ["private"]  # only the track that changed
        for path in routes:
            body = client.get(path).text
            assert "first-entry" in body and "second-entry" in body, path
        page = operator_browser(app).get(f"/submissions/{second}").text  # its rank on each board it ran
        assert page.count('<div class="muted small">of 2</div>') == len(DATASETS)
        assert client.get(f"/api/v1/leaderboards/diverse/math?submission={sid}").json()["total"] == 1
    assert worker.run_once() == []  # nothing changed: nothing computed


def test_readers_keep_the_previous_version_while_the_next_is_computed(quiet_app) -> None:
    """One worker computes (the other finds the track claimed and computes nothing); readers get the previous
    version meanwhile, and the new one the moment it is published."""
    app = quiet_app
    submit(app, "alice", "builtin:random", name="first-entry")
    drain(app)
    assert publisher(app).publish("private")
    submit(app, "bob", "builtin:dbl", name="second-entry")
    drain(app)
    gate = Gate(engine(app))
    first = publisher(app, gate)
    running = threading.Thread(target=first.publish, args=("private",))
    with TestClient(app) as client:
        running.start()
        assert gate.entered.wait(60)
        rival = Gate(engine(app))
        rival.go.set()
        assert not publisher(app, rival).publish("private") and rival.calls == 0
        for _ in range(3):
            assert names(client) == ["first-entry"]
        gate.go.set()
        running.join(60)
        assert names(client) == ["first-entry", "second-entry"]


def test_a_worker_that_dies_mid_computation_leaves_the_previous_version_served(quiet_app) -> None:
    app = quiet_app
    submit(app, "alice", "builtin:random", name="first-entry")
    drain(app)
    assert publisher(app).publish("private")
    before = published(app)
    submit(app, "bob", "builtin:dbl", name="second-entry")
    drain(app)
    crashing = Gate(engine(app), fail=True)
    crashing.go.set()
    with pytest.raises(RuntimeError):
        publisher(app, crashing).publish("private")
    with TestClient(app) as client:
        assert names(client) == ["first-entry"]
        assert published(app) == before
        # a worker killed outright never releases its claim: the others wait for the lease to lapse
        dead = publisher(app, lease_s=0.5)
        assert dead._claim("private")
        assert not publisher(app).publish("private")
        assert names(client) == ["first-entry"]
        time.sleep(0.6)
        assert publisher(app).publish("private")
        assert names(client) == ["first-entry", "second-entry"]


def test_a_restarted_server_serves_the_stored_boards_without_computing(
    db_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    app = make_app(db_url, tmp_path, board_worker="thread")
    try:
        submit(app, "alice", "builtin:random", name="first-entry")
        drain(app)
        with TestClient(app) as client:
            assert names(client) == ["first-entry"]
        submit(app, "bob", "builtin:dbl", name="second-entry")  # finishes while no server runs
        drain(app)
    finally:
        app.state.runtime.dispose()
    version = published(app)[0]

    def never(*_: Any) -> Any:
        raise AssertionError("a restarted server computed a board before serving")

    monkeypatch.setattr(board_engine, "compute_snapshot", never)
    app = make_app(db_url, tmp_path, board_worker="off", board_wait_s=0)
    try:
        with TestClient(app) as client:
            assert names(client) == ["first-entry"]  # at once, from SQL
            assert "first-entry" in client.get("/").text
        assert published(app)[0] == version
    finally:
        app.state.runtime.dispose()


def test_two_readers_on_one_database_agree(quiet_app) -> None:
    """Two API processes' readers: the same pages, and both move to a new version when it is published."""
    app = quiet_app
    submit(app, "alice", "builtin:random", name="first-entry")
    drain(app)
    assert publisher(app).publish("private")
    one, two = reader(app), reader(app)
    pages = [(c.board_page("diverse", "math", view="all"), c.grid_page(view="all")) for c in (one, two)]
    assert pages[0] == pages[1] and len(pages[0][0]["entries"]) == 1
    submit(app, "bob", "builtin:dbl", name="second-entry")
    drain(app)
    assert publisher(app).publish("private")
    pages = [(c.board_page("diverse", "math", view="all"), c.grid_page(view="all")) for c in (one, two)]
    assert pages[0] == pages[1] and len(pages[0][0]["entries"]) == 2


def test_unchanged_boards_keep_their_parts_and_a_refresh_recomputes(quiet_app) -> None:
    app = quiet_app
    submit(app, "alice", "builtin:random", name="first-entry")
    drain(app)
    worker = publisher(app)
    assert worker.publish("private")
    with app.state.runtime.read_session() as s:
        boards = dict(s.get(BoardPublication, "private").boards)
    submit_direct(app, "bob", "builtin:dbl", datasets=("diverse",), groups=GROUPS)  # longboard's stays
    drain(app)
    assert worker.publish("private")
    with app.state.runtime.read_session() as s:
        after = dict(s.get(BoardPublication, "private").boards)
    assert after["longboard/math/closed"] == boards["longboard/math/closed"]
    assert after["diverse/math/closed"] != boards["diverse/math/closed"]
    gate = Gate(engine(app))
    gate.go.set()
    assert not publisher(app, gate).publish("private") and gate.calls == 0  # nothing changed
    with app.state.runtime.session() as s:
        assert request_recompute(s, "private") == 1
    publisher(app, gate).publish("private")
    assert gate.calls == 1 and published(app)[1] is not None


def test_the_board_worker_process_publishes_on_its_own(db_url: str, tmp_path: Path) -> None:
    app = make_app(db_url, tmp_path, board_worker="process", board_poll_s=0.2)
    try:
        with TestClient(app) as client:
            submit(app, "alice", "builtin:random", name="first-entry")
            drain(app)
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                response = client.get(BOARD)
                if response.status_code == 200 and response.json()["entries"]:
                    break
                time.sleep(0.2)
            assert names(client) == ["first-entry"]
            assert app.state.board_worker.process.is_alive()
        assert not app.state.board_worker.process.is_alive()  # stopped with the server
    finally:
        app.state.runtime.dispose()


def test_refresh_boards_command_has_the_worker_recompute(quiet_app, monkeypatch: pytest.MonkeyPatch) -> None:
    """``robobpp db refresh-boards``: the worker recomputes although no submission finished, and the boards
    stay served until it has."""
    from typer.testing import CliRunner

    from robobpp.cli import app as cli_app
    from robobpp.cli import register_commands

    app = quiet_app
    submit(app, "alice", "builtin:random", name="first-entry")
    drain(app)
    assert publisher(app).publish("private") and publisher(app).publish("public")
    monkeypatch.setenv("ROBOBPP_DATABASE_URL", app.state.settings.sqlalchemy_url)
    register_commands()
    shown = CliRunner().invoke(cli_app, ["db", "refresh-boards", "--track", "private"])
    assert shown.exit_code == 0, shown.output
    assert "recompute 1 track(s)" in shown.output
    assert published(app)[1] is None and published(app, "public")[1] is not None
    with TestClient(app) as client:
        assert names(client) == ["first-entry"]  # still served meanwhile
    gate = Gate(engine(app))
    gate.go.set()
    assert not publisher(app, gate).publish("public") and gate.calls == 0  # the other track: untouched
    publisher(app, gate).publish("private")
    assert gate.calls == 1 and published(app)[1] is not None


def _rankless(entry: Mapping[str, Any]) -> str:
    served = {k: v for k, v in entry.items() if not k.startswith("_") and not k.startswith("best_")}
    if "cells" in served:
        served["cells"] = {k: {**c, "rank": None} for k, c in served["cells"].items()}
    return json.dumps({**served, "rank": None}, default=str, sort_keys=True)


def _contents(worker: BoardPublisher) -> dict[tuple[Any, int], tuple[str, Any]]:
    """Every all-entries row of every board and grid of the private track as the worker's engine last
    computed them: its content without ranks, and its ranks."""
    out = {}
    for key, board in worker.engine.current("private").items():  # type: ignore[attr-defined]
        for e in board.entries if isinstance(board, Board) else board.rows:
            ranks = (e["rank"], {k: c["rank"] for k, c in e.get("cells", {}).items()})
            out[(key, e["submission_id"])] = (_rankless(e), ranks)
    return out


def test_an_update_writes_only_the_entry_rows_whose_content_changed(quiet_app) -> None:
    """Through the real engine: the rows written are those whose content (ranks aside) changed, and the
    pages read back are the engine's boards."""
    app = quiet_app
    for who, url in (("a", "builtin:random"), ("b", "builtin:lsah")):
        submit(app, who, url)
    drain(app)
    worker = publisher(app)
    assert worker.publish("private")
    first = _contents(worker)
    assert worker.rows_written == len(first)
    submit(app, "c", "builtin:dbl")  # between the two
    drain(app)
    assert worker.publish("private")
    second = _contents(worker)
    moved = {k for k, v in second.items() if k not in first or first[k][0] != v[0]}
    assert worker.rows_written == len(moved)
    cache = reader(app)
    shown = worker.engine.current("private")  # type: ignore[attr-defined]
    for dataset in DATASETS:
        got = cache.board_page(dataset, "math", "private", "closed", "all")
        assert got == json.loads(to_json(board_view(as_board(shown[(dataset, "math")]), "all")))
        # a page of one entry carries the whole view's column tops (what its pages highlight)
        one = cache.board_page(dataset, "math", "private", "closed", "all", limit=1, offset=2)
        scores = [e["score"] for e in got["entries"]]
        assert one["column_tops"]["score"] == sorted(set(scores), reverse=True)[:4]
        assert (
            one["column_tops"]["space_utilization"]
            == sorted({e["metrics"]["space_utilization"] for e in got["entries"]}, reverse=True)[:4]
        )
    assert cache.grid_page("private", "closed", "all") == json.loads(
        to_json(grid_view(as_grid(shown["grid"]), "all"))
    )


def test_a_reader_of_the_previous_version_never_sees_rows_of_the_next(quiet_app) -> None:
    """A reader that named a version reads that version's rows although the next one replaced some of
    them; once that version is gone (two publications later) it reads the publication again."""
    app = quiet_app
    submit(app, "a", "builtin:random")
    submit(app, "b", "builtin:dbl")
    drain(app)
    worker = publisher(app)
    assert worker.publish("private")
    before = board_view(as_board(worker.engine.current("private")[("diverse", "math")]), "all")  # type: ignore[attr-defined]
    slow = reader(app, refresh_s=3600)  # keeps the version it read first
    assert slow.board_page("diverse", "math", view="best")["total"] == 2
    submit(app, "c", "builtin:lsah")
    drain(app)
    assert worker.publish("private")
    assert worker.rows_written > 0
    assert slow.board_page("diverse", "math", view="all") == json.loads(to_json(before))
    submit(app, "d", "builtin:random")
    drain(app)
    assert worker.publish("private")
    fresh = reader(app).board_page("diverse", "math", view="all")
    slow._parts.clear()  # its rows of the first version are gone from SQL too
    with pytest.raises(boards_module.VersionGone):  # served bodies retry after reading the publication again
        slow.board_page("diverse", "math", view="all")
    slow.publication("private", force=True)
    assert slow.board_page("diverse", "math", view="all") == fresh
    assert len(fresh["entries"]) == 4


class Scripted:
    """An engine that hands out the boards it is given (one Math board), as the real one would."""

    def __init__(self) -> None:
        self.board = _board([])

    def keys(self, track: str) -> list[Any]:
        return [("diverse", "math")]

    def update(self, track: str) -> Mapping[Any, Any]:
        return {("diverse", "math"): self.board}

    refresh = update


def _board(
    entries: list[tuple[int, float]], owners: dict[int, str] | None = None, unranked: Sequence[Row] = ()
) -> Board:
    """A board of entries (submission id, score), ranked by score; ``owners``: participants by submission id
    (by default each its own); ``unranked``: its unranked entries."""
    owner = {sid: (owners or {}).get(sid, f"p{sid}") for sid, _ in entries}
    counts = Counter(owner.values())
    rows = []
    for rank, (sid, score) in enumerate(sorted(entries, key=lambda e: -e[1]), start=1):
        rows.append(
            {
                "submission_id": sid,
                "name": f"n{sid}",
                "participant": owner[sid],
                "baseline": False,
                "rank": rank,
            }
            | {"rank_low": None, "rank_high": None, "score": score, "best": True, "_column": rank - 1}
            | {"entries_submitted": counts[owner[sid]]}
        )
    index = {sid: i for i, (sid, _) in enumerate(sorted(entries, key=lambda e: -e[1]))}
    return Board("diverse", "math", "private", 0, rows, list(unranked), rows, index, {})


def test_an_entry_ranked_above_others_writes_its_row_alone(quiet_app) -> None:
    """An arriving entry moves the rank of everyone below it and nothing else of theirs: one row is written,
    and the pages read back carry the new ranks."""
    app = quiet_app
    scripted = Scripted()
    worker = publisher(app, scripted)
    scripted.board = _board([(1, 0.9), (2, 0.5), (3, 0.1)])
    assert worker.publish("private", force=True) and worker.rows_written == 3
    scripted.board = _board([(1, 0.9), (2, 0.5), (3, 0.1), (4, 0.7)])
    assert worker.publish("private", force=True) and worker.rows_written == 1
    page = reader(app).board_page("diverse", "math", view="all")
    assert [(e["submission_id"], e["rank"]) for e in page["entries"]] == [(1, 1), (4, 2), (2, 3), (3, 4)]
    assert page == json.loads(to_json(board_view(scripted.board, "all")))
    scripted.board = _board([(1, 0.9), (2, 0.6), (3, 0.1), (4, 0.7)])  # one score moved, no rank
    assert worker.publish("private", force=True) and worker.rows_written == 1
    assert (
        reader(app).board_page("diverse", "math", view="all", offset=2, limit=1)["entries"][0]["score"] == 0.6
    )
    assert not worker.publish("private", force=True) and worker.rows_written == 0  # nothing changed
    # a second entry of participant p1: its other entry's count moves, and that row is not written again
    scripted.board = _board([(1, 0.9), (2, 0.6), (3, 0.1), (4, 0.7), (5, 0.3)], {5: "p1"})
    assert worker.publish("private", force=True) and worker.rows_written == 1
    page = reader(app).board_page("diverse", "math", view="all")
    assert {e["submission_id"]: e["entries_submitted"] for e in page["entries"]} == {
        1: 2,
        2: 1,
        3: 1,
        4: 1,
        5: 2,
    }
    assert page == json.loads(to_json(board_view(scripted.board, "all")))


def _unranked(*sids: int) -> list[dict[str, Any]]:
    return [
        {"submission_id": sid, "name": f"n{sid}", "participant": f"p{sid}", "baseline": False}
        | {"status": "partial", "reason": "not every group", "entries_submitted": 1}
        for sid in sids
    ]


def _stored_parts(app: Any, key: str = "diverse/math/closed") -> dict[int, set[str]]:
    """The board's parts in SQL other than its rows, by version."""
    with app.state.runtime.read_session() as s:
        rows = s.execute(
            select(BoardPart.version, BoardPart.part).where(
                BoardPart.board == key, BoardPart.part.not_like("e:%")
            )
        ).all()
    out: dict[int, set[str]] = {}
    for version, part in rows:
        out.setdefault(version, set()).add(part)
    return out


def _shown(app: Any, version: int, key: str = "diverse/math/closed") -> set[tuple[str, int]]:
    """The parts (other than rows) a published version reads: its head and order, and its chunks where its
    head says they are."""
    with app.state.runtime.read_session() as s:
        head = json.loads(
            s.execute(
                select(BoardPart.body).where(
                    BoardPart.board == key, BoardPart.version == version, BoardPart.part == "head"
                )
            ).scalar_one()
        )
    return {("head", version), ("order", version)} | {(n, at[0]) for n, at in head["parts"].items()}


def test_an_unchanged_chunk_is_written_once_and_old_parts_go(quiet_app) -> None:
    """A chunk whose content did not change (the unranked entries, the best view above a new entry) stays
    where an earlier version wrote it and is read from there; what neither the current nor the previous
    version shows is removed."""
    app = quiet_app
    scripted = Scripted()
    worker = publisher(app, scripted)
    entries = [(i, 1.0 - i / 500) for i in range(1, 251)]  # three chunks of the best view
    scripted.board = _board(entries, unranked=_unranked(900, 901))
    assert worker.publish("private", force=True)
    first = published(app)[0]
    for k, score in enumerate((0.001, 0.0005, 0.0001)):  # each below everyone: only the last best chunk moves
        scripted.board = _board([*entries, (300 + k, score)], unranked=_unranked(900, 901))
        entries.append((300 + k, score))
        assert worker.publish("private", force=True)
        version = published(app)[0]
        page = reader(app).board_page("diverse", "math", view="all", limit=500)
        assert page == json.loads(to_json(board_view(scripted.board, "all", limit=500)))
        best = reader(app).board_page("diverse", "math", view="best", offset=0, limit=300)
        assert best == json.loads(to_json(board_view(scripted.board, "best", limit=300)))
        stored = _stored_parts(app)
        assert "unranked:0" in stored[first] and all(
            "unranked:0" not in stored[v] for v in stored if v != first
        )
        assert "best:0" in stored[first] and "best:2" in stored[version]
        # nothing is left that neither this version nor the previous one shows
        shown = _shown(app, version) | _shown(app, version - 1)
        assert {(n, v) for v, names in stored.items() for n in names} == shown
    assert reader(app).board_page("diverse", "math", submission_id=901)["unranked"][0]["submission_id"] == 901
    # the unranked entries change: their chunk is written again, and the first one goes once no version shows it
    scripted.board = _board(entries, unranked=_unranked(900))
    assert worker.publish("private", force=True)
    scripted.board = _board(entries[:-1], unranked=_unranked(900))
    assert worker.publish("private", force=True)
    assert "unranked:0" not in _stored_parts(app).get(first, set())
    assert _stored_parts(app)[first] == {"best:0", "best:1"}  # still shown
    page = reader(app).board_page("diverse", "math", view="all")
    assert page == json.loads(to_json(board_view(scripted.board, "all")))


def _as_layout_3(app: Any, key: str) -> None:
    """Rewrite the published version of board ``key`` as layout 3 stored it: ``order`` as int64 (ids, ranks,
    cells), a ``rows`` manifest (ids ascending, row versions, hashes), an ``index`` (id -> position), every
    chunk at the version itself, a head without the chunks' versions."""
    import numpy as np

    from robobpp.boards.store import Order

    with app.state.runtime.session() as s:
        publication = s.get(BoardPublication, "private")
        version = publication.boards[key][0]
        publication.boards = {**publication.boards, key: [version, "digested by layout 3"]}
        parts = {p.part: p for p in s.scalars(select(BoardPart).where(BoardPart.board == key))}
        head_part = next(p for p in parts.values() if p.part == "head" and p.version == version)
        order_part = next(p for p in parts.values() if p.part == "order" and p.version == version)
        head = json.loads(head_part.body)
        order = Order.decode(order_part.body)
        n, c = len(order.ids), order.cells.shape[1]
        order_part.body = (
            np.array([n, c], dtype=np.int64).tobytes()
            + order.ids.tobytes()
            + order.ranks.tobytes()
            + order.cells.astype(np.int64).tobytes()
        )
        ids, versions, hashes = order.by_id()
        rows = np.array([n], dtype=np.int64).tobytes() + ids.tobytes() + versions.tobytes() + hashes.tobytes()
        unranked = head.get("unranked", [])
        every = np.concatenate([order.ids, np.array(unranked, dtype=np.int64)])
        at = np.concatenate([np.arange(n), -1 - np.arange(len(unranked))])
        by = np.argsort(every)
        s.add(BoardPart(track="private", board=key, version=version, part="rows", body=rows))
        if c == 0:
            index = every[by].tobytes() + at[by].astype(np.int64).tobytes()
            s.add(BoardPart(track="private", board=key, version=version, part="index", body=index))
        for name, (held, _) in head.pop("parts").items():
            if held != version:
                body = s.execute(
                    select(BoardPart.body).where(
                        BoardPart.board == key, BoardPart.part == name, BoardPart.version == held
                    )
                ).scalar_one()
                s.add(BoardPart(track="private", board=key, version=version, part=name, body=body))
        head.pop("layout")
        head.pop("unranked", None)
        head_part.body = to_json(head)


def test_a_version_stored_by_layout_3_is_served_and_replaced(quiet_app) -> None:
    """After an upgrade, readers serve the boards an older server stored (layout 3) until the upgraded worker
    publishes its own, which keeps the stored rows whose content is the same."""
    app = quiet_app
    for who, url in (("a", "builtin:random"), ("b", "builtin:lsah"), ("c", "builtin:dbl")):
        submit(app, who, url)
    submit_direct(app, "d", "builtin:random", datasets=("diverse",), groups=GROUPS)  # not on every board
    drain(app)
    worker = publisher(app)
    assert worker.publish("private")
    cache = reader(app)
    pages = {
        "board": cache.board_page("diverse", "math", "private", "closed", "all"),
        "grid": cache.grid_page("private", "closed", "all"),
        "one": cache.board_page("diverse", "math", "private", "closed", "all", submission_id=3),
    }
    assert pages["board"]["entries"] and pages["grid"]["rows"]
    _as_layout_3(app, "diverse/math/closed")
    _as_layout_3(app, "grid/closed")
    old = reader(app)
    assert old.board_page("diverse", "math", "private", "closed", "all") == pages["board"]
    assert old.grid_page("private", "closed", "all") == pages["grid"]
    assert old.board_page("diverse", "math", "private", "closed", "all", submission_id=3) == pages["one"]
    upgraded = publisher(app)  # a fresh worker: it knows the stored version only from SQL
    assert upgraded.publish("private", force=True)
    assert upgraded.rows_written == 0  # every row's content is the same
    fresh = reader(app)
    assert fresh.board_page("diverse", "math", "private", "closed", "all") == pages["board"]
    assert fresh.grid_page("private", "closed", "all") == pages["grid"]


def test_a_reader_keeps_only_the_current_version_of_a_boards_order(quiet_app) -> None:
    """A reader decodes each board's version once and drops the older version's decoded order when a newer
    one is read (it grew with N on every publication before, kept until 4,096 newer parts pushed it out)."""
    app = quiet_app
    submit(app, "alice", "builtin:random", name="first-entry")
    drain(app)
    assert publisher(app).publish("private")
    cache = reader(app)
    key = board_key("diverse", "math", "closed")
    cache.board_page("diverse", "math", "private", "closed", "all", 10, 0)
    first = published(app)[0]
    submit(app, "bob", "builtin:dbl", name="second-entry")
    drain(app)
    assert publisher(app).publish("private")
    cache.publication("private", force=True)
    cache.board_page("diverse", "math", "private", "closed", "all", 10, 0)
    versions = [k[2] for k in cache._parts if k[3] == "#" and k[:2] == ("private", key)]
    assert len(versions) == 1 and versions[0] > first


def _bodies_watched(app: Any, monkeypatch: pytest.MonkeyPatch) -> tuple[BoardPublisher, list[int], Any]:
    """Two finished submissions and a publisher whose serialised boards are watched: each board's bodies
    as a weak reference (``made``), and how many of those made before were alive when the next was made."""
    for who, url in (("a", "builtin:dbl"), ("b", "builtin:random")):
        submit(app, who, url)
    drain(app)
    made: list[weakref.ref[Any]] = []
    alive_at_each: list[int] = []
    real = BoardPublisher._stored

    def watched(self: BoardPublisher, track: str, key: str, board: Published) -> Any:
        alive_at_each.append(_alive(made))
        hashed = real(self, track, key, board)
        made.append(weakref.ref(hashed))
        return hashed

    monkeypatch.setattr(BoardPublisher, "_stored", watched)
    return publisher(app), alive_at_each, made


def _alive(refs: list[weakref.ref[Any]]) -> int:
    gc.collect()
    return sum(r() is not None for r in refs)


def test_a_publication_serialises_each_board_as_it_writes_it(
    quiet_app, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A first publication serialises every row of every board; holding every board's bodies at once was
    gigabytes at 100,000 submissions. Each board's are made when it is written, the previous board's gone."""
    worker, alive_at_each, made = _bodies_watched(quiet_app, monkeypatch)
    assert worker.publish("private")
    assert len(made) >= 3, "every board and grid of the track is serialised"
    # the board written last is still referenced when the next is made, no earlier one
    assert max(alive_at_each) <= 1, alive_at_each
    assert names(TestClient(quiet_app)), "and the publication is served"


def _together(n: int, call: Any) -> list[Any]:
    """``call()`` in ``n`` threads released at once; their results."""
    start = threading.Barrier(n)
    out: list[Any] = [None] * n

    def run(i: int) -> None:
        start.wait()
        out[i] = call()

    threads = [threading.Thread(target=run, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    return out


def test_readers_of_a_new_version_decode_it_and_build_its_page_once(
    quiet_app, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Twenty readers arriving together at a version nobody read yet (every reader after a publication): one
    decodes it and builds the page, the others wait for it and get the same body. At 100,000 entries each
    decoding the grid's order, and each building the page, made them queue for hundreds of milliseconds."""
    app = quiet_app
    for who, url in (("a", "builtin:dbl"), ("b", "builtin:random")):
        submit(app, who, url)
    drain(app)
    assert publisher(app).publish("private")
    decoded, built = Counter[str](), Counter[str]()
    real_decode = board_store.decode_version  # the reader's name for it is patched below

    def slow_decode(version: int, parts: Mapping[str, bytes]) -> Any:
        decoded["order"] += 1
        time.sleep(0.2)  # long enough for every other reader to arrive meanwhile
        return real_decode(version, parts)

    monkeypatch.setattr(boards_module, "decode_version", slow_decode)
    cache = reader(app)

    def page() -> bytes:
        built["page"] += 1
        time.sleep(0.1)
        return to_json(cache.grid_page("private", "closed", "all"))

    key = ("grid", "all")
    bodies = _together(20, lambda: cache.response("private", "grid/closed", key, page))
    assert decoded["order"] == 1 and built["page"] == 1, (decoded, built)
    assert len(set(bodies)) == 1 and json.loads(bodies[0])["rows"]


def test_one_reader_reads_the_publication_while_the_others_serve_the_one_they_know(
    quiet_app, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Past ``refresh_s``, one reader asks SQL for the track's publication (at 100,000 submissions its
    version is a count of them); readers arriving meanwhile are answered from the one read before, the
    served body without a thread. Nobody waits unless nothing was read yet."""
    app = quiet_app
    submit(app, "a", "builtin:dbl")
    drain(app)
    assert publisher(app).publish("private")
    cache = reader(app, refresh_s=0.05)
    key = ("grid", "best")
    body = cache.response("private", "grid/closed", key, lambda: to_json(cache.grid_page("private")))
    asked = Counter[str]()
    inside, release = threading.Event(), threading.Event()
    real_source = board_store.board_source

    def slow_source(*args: Any) -> Any:
        asked["source"] += 1
        inside.set()
        assert release.wait(30)
        return real_source(*args)

    monkeypatch.setattr(boards_module, "board_source", slow_source)
    time.sleep(0.1)  # the publication read above is now due again
    assert cache.fresh_response("private", "grid/closed", key) is None  # due: a thread is to read it
    first = threading.Thread(target=cache.publication, args=("private",))
    first.start()
    assert inside.wait(30)
    t0 = time.perf_counter()
    others = _together(10, lambda: cache.publication("private"))
    waited = time.perf_counter() - t0
    assert cache.fresh_response("private", "grid/closed", key) == body  # one read in flight: served as known
    release.set()
    first.join(30)
    assert asked["source"] == 1 and waited < 5, (asked, waited)
    assert {p.version for p in others} == {published(app)[0]}
    forced = _together(3, lambda: cache.publication("private", force=True))
    assert asked["source"] >= 2, "forced: read again (by this reader or one that began after it asked)"
    assert all(p is not None and p.version == published(app)[0] for p in forced)


def test_readers_of_a_server_with_nothing_published_wait_for_the_worker_together(quiet_app) -> None:
    """Before the first publication every reader waits up to ``wait_s`` for the worker: one of them reads
    and waits, the others take what it found (they neither wait in turn nor each poll SQL)."""
    cache = reader(quiet_app, wait_s=0.3)
    found = _together(10, lambda: cache.publication("private"))
    assert found == [None] * 10
    assert cache.waited == 1, cache.waited


def test_timed_full_computations_take_at_most_a_tenth_of_the_workers_time(
    quiet_app, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A full computation is due ``full_s`` after the last, but no sooner than ten times its duration: at
    100,000 submissions one takes 18 minutes, and every 300 s the worker would compute in full most of the
    time while finished submissions wait for it."""
    app = quiet_app
    now = [0.0]

    class Clock:
        def __getattr__(self, name: str) -> Any:
            return getattr(time, name)

        def monotonic(self) -> float:
            return now[0]

    class Timed(Scripted):
        """An update costs 5 s of the worker's clock, a full computation 1,000 s."""

        def __init__(self) -> None:
            super().__init__()
            self.calls: list[str] = []

        def update(self, track: str) -> Mapping[Any, Any]:
            return self._computed("update", 5.0)

        def refresh(self, track: str) -> Mapping[Any, Any]:
            return self._computed("full", 1000.0)

        def _computed(self, kind: str, cost: float) -> Mapping[Any, Any]:
            self.calls.append(kind)
            now[0] += cost
            return {("diverse", "math"): self.board}

    monkeypatch.setattr(board_worker_module, "time", Clock())
    timed = Timed()
    timed.board = _board([(1, 0.9)])
    worker = BoardWorker(publisher(app, timed), full_s=300, cheap_s=0, tracks=("private",))
    worker.run_once()  # the first pass is a full one (1,000 s)
    now[0] += 400  # past full_s, but a full pass now would be its 1,000 s in 1,400
    submit(app, "a", "builtin:random")
    drain(app)
    worker.run_once()
    assert timed.calls == ["full", "update"]
    now[0] += 10_000 - 405  # ten times the last full computation after it
    worker.run_once()
    assert timed.calls[-1] == "full", "due again after ten times its duration"


def test_a_long_full_computation_says_how_far_it_is(
    quiet_app, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Past ``PROGRESS_AFTER_S`` a full computation logs each board it finished (18 silent minutes at
    100,000 submissions before)."""
    submit(quiet_app, "a", "builtin:dbl")
    drain(quiet_app)
    monkeypatch.setattr(board_engine, "PROGRESS_AFTER_S", 0.0)
    with caplog.at_level("INFO", logger="robobpp.server"):
        engine(quiet_app).update("private")
    said = [r.getMessage() for r in caplog.records if "in full" in r.getMessage()]
    assert len(said) == len(DATASETS), said  # one Math board per dataset here
    assert said[-1].startswith(
        f"computing the private boards in full: {len(DATASETS)} of {len(DATASETS)} done"
    )


def test_a_publication_hands_its_bodies_heap_back_once_they_are_gone(
    quiet_app, monkeypatch: pytest.MonkeyPatch
) -> None:
    """glibc keeps the heap a publication's row bodies took (150 MB after a first publication at 10,000
    submissions, the board worker's largest share beside the engine): the publisher trims it after writing,
    when no board's bodies are referenced any longer, and publishes what it computed."""
    import robobpp.boards.worker as board_worker

    worker, _, made = _bodies_watched(quiet_app, monkeypatch)
    alive_at_trim: list[int] = []
    monkeypatch.setattr(board_worker, "trim_heap", lambda: alive_at_trim.append(_alive(made)))
    assert worker.publish("private")
    assert made and alive_at_trim == [0], (len(made), alive_at_trim)
    assert names(TestClient(quiet_app)), "and the publication is served"
