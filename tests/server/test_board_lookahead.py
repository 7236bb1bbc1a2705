"""One board per lookahead, on SQLite and PostgreSQL: a submission that saw K > 0 next boxes ranks only on the
boards of K (closed loop), normalised among them, never beside lookahead-0 entries; the board engine keeps them
apart incrementally as a full computation does, brings a lookahead's boards with its first entry and takes them
away with its last; the API, the pages, the CLI and the exports say which lookahead a board shows."""

from __future__ import annotations

import csv
import io
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select
from typer.testing import CliRunner

from robobpp.boards.engine import BoardEngine, board_id, grid_id, lookahead_of
from robobpp.boards.ranking import build_board
from robobpp.boards.records import Board, Grid, Published, as_board
from robobpp.db import queries
from robobpp.db.models import BoardPart, Submission
from robobpp.db.session import transaction
from tests.server.conftest import submit_direct
from tests.server.test_board_engine import DATASETS, SETTINGS, add_submission, factory, same, scratch
from tests.server.test_board_publishing import publisher
from tests.server.test_scale import ADMIN, GROUPS, drain, make_app, operator_browser, submit

__all__ = ["factory"]  # the fixture, shared with the engine's tests

TEN = [board_id(d, st, "closed", 10) for st in SETTINGS for d in DATASETS]


def shown_ids(item: Published | Mapping[str, Any]) -> set[int]:
    """Every submission a board or grid lists, ranked or apart (the engine's, or a page as served)."""
    if isinstance(item, Board):
        listed = [*item.entries, *item.unranked]
    elif isinstance(item, Grid):
        listed = [*item.rows, *item.apart]
    else:
        listed = [*item.get("entries", item.get("rows", [])), *item.get("unranked", item.get("apart", []))]
    return {e["submission_id"] for e in listed}


def test_a_lookahead_ranks_on_boards_of_its_own(factory: Any) -> None:
    zero = [add_submission(factory, f"team-{i % 3}", 0.2 + 0.1 * i, seed=i, paper=True) for i in range(5)]
    engine = BoardEngine(factory, DATASETS, SETTINGS)
    first = engine.update("private")
    assert set(first) == set(engine.keys("private")) and all(b.lookaheads == [0] for b in first.values())
    before = {
        k: [(e["submission_id"], e["score"]) for e in as_board(b).entries]
        for k, b in first.items()
        if isinstance(k, tuple)
    }

    # two entries that saw 10 next boxes, one far above everyone (its physical runs under the paper protocol
    # too: those are on no board)
    seer = add_submission(factory, "seer", 3.0, seed=50, lookahead=10, paper=True)
    other = add_submission(factory, "seer-2", 0.1, seed=51, lookahead=10)
    changed = engine.update("private")
    # the set of lookaheads moved: every board and grid says so, all handed out again
    assert set(changed) == set(engine.keys("private")) == set(first) | {*TEN, grid_id("closed", 10)}
    for key, board in changed.items():
        assert board.lookaheads == [0, 10] and board.lookahead == lookahead_of(key)
        assert shown_ids(board) == ({seer, other} if lookahead_of(key) else set(zero)), key
    # nothing of the lookahead-0 boards moved: the seer entered none of their normalisations
    assert {
        k: [(e["submission_id"], e["score"]) for e in as_board(changed[k]).entries] for k in before
    } == before
    # the lookahead-10 board is the board of those two alone: its own ranks and normalisation
    with factory() as s:
        rows = queries.board_rows(s, "diverse", "math", "private", lookahead=10)
    alone = build_board(rows, "diverse", "math", "private")
    ten = as_board(changed[board_id("diverse", "math", "closed", 10)])
    assert [(e["submission_id"], e["rank"]) for e in ten.entries] == [(seer, 1), (other, 2)]
    assert [e["score"] for e in ten.entries] == pytest.approx([e["score"] for e in alone.entries], abs=1e-12)
    assert ten.entries[0]["normalized"]["space_utilization"] == 1.0
    same(changed, scratch(factory), ranks=False, tol=1e-12)

    # an arrival of one lookahead touches the boards and grid of that lookahead only
    add_submission(factory, "team-9", 0.5, seed=60)
    assert {lookahead_of(k) for k in engine.update("private")} == {0}
    add_submission(factory, "seer-3", 0.5, seed=61, lookahead=10)
    assert {lookahead_of(k) for k in engine.update("private")} == {10}
    # the full computation equals the from-scratch one, every lookahead's boards included
    same(engine.refresh("private"), scratch(factory), tol=1e-12)

    # the last lookahead-10 entries leave: its boards go, and every board says so
    with transaction(factory) as s:
        for sub in s.execute(select(Submission).where(Submission.lookahead == 10)).scalars():
            s.delete(sub)
    changed = engine.update("private")
    assert set(changed) == set(engine.keys("private")) == set(first)
    assert all(b.lookaheads == [0] for b in changed.values())
    same(changed, scratch(factory), ranks=False, tol=1e-12)


def test_the_reproduction_compares_lookahead_zero_baselines_only(factory: Any) -> None:
    plain = add_submission(factory, "dbl", 0.5, seed=1, builtin=True, paper=True)
    add_submission(factory, "dbl-seer", 0.9, seed=2, builtin=True, paper=True, lookahead=10)
    with factory() as s:
        assert {r["submission_id"] for r in queries.baseline_runs(s, "private")} == {plain}


@pytest.fixture
def app(db_url: str, tmp_path: Path) -> Iterator[Any]:
    """Boards published by a test's own publisher; readers never wait."""
    app = make_app(db_url, tmp_path, board_worker="off", board_wait_s=0)
    yield app
    app.state.runtime.dispose()


def table(html: str, name: str) -> str:
    """The HTML of one table of a page."""
    start = html.index(f'id="{name}"')
    return html[start : html.index("</table>", start)]


def test_api_pages_cli_and_exports_show_which_lookahead_a_board_is(app: Any) -> None:
    alice, bob = submit(app, "alice", "builtin:dbl"), submit(app, "bob", "builtin:random")
    seer = submit_direct(
        app, "carol", "builtin:lsah", datasets=DATASETS, groups=GROUPS, lookahead=10, name="seer"
    )
    drain(app)
    assert publisher(app).publish("private")
    client = TestClient(app)
    admin = {"Authorization": f"Bearer {ADMIN}"}

    # the API: the leaderboard is lookahead 0; ?lookahead=10 is the seer's board, alone
    board = client.get("/api/v1/leaderboards/diverse/math", params={"view": "all"}).json()
    assert shown_ids(board) == {alice, bob} and (board["lookahead"], board["lookaheads"]) == (0, [0, 10])
    ten = client.get("/api/v1/leaderboards/diverse/math", params={"view": "all", "lookahead": 10}).json()
    assert shown_ids(ten) == {seer} and ten["lookahead"] == 10 and ten["entries"][0]["rank"] == 1
    grid = client.get("/api/v1/leaderboards", params={"lookahead": 10, "view": "all"}).json()
    assert [r["submission_id"] for r in grid["rows"]] == [seer] and grid["lookahead"] == 10
    assert seer not in shown_ids(client.get("/api/v1/leaderboards", params={"view": "all"}).json())
    missing = client.get("/api/v1/leaderboards/diverse/math", params={"lookahead": 3})
    assert missing.status_code == 404 and "lookahead 0, 10" in missing.json()["detail"]
    paper = client.get("/api/v1/leaderboards", params={"lookahead": 10, "protocol": "paper"})
    assert paper.status_code == 404 and "lookahead 0 only" in paper.json()["detail"]
    assert client.get("/api/v1/leaderboards", params={"lookahead": 11}).status_code == 422
    sub = client.get(f"/api/v1/submissions/{seer}", headers=admin).json()
    assert sub["lookahead"] == 10 and sub["provenance"]["lookahead"] == 10

    # the pages: a switch, and each board says which lookahead it shows
    home = client.get("/").text
    assert 'data-role="lookahead"' in home and 'href="?view=best&lookahead=10"' in home
    assert "seer" not in table(home, "overall") and "alice" in table(home, "overall")
    home_ten = client.get("/", params={"lookahead": 10}).text
    assert "· lookahead 10</span></h1>" in home_ten and 'data-role="lookahead-note"' in home_ten
    assert "seer" in table(home_ten, "overall") and "alice" not in table(home_ten, "overall")
    assert "/boards/diverse/math?lookahead=10" in home_ten
    page = client.get("/boards/diverse/math", params={"lookahead": 10, "view": "all"}).text
    assert "· lookahead 10</span></h1>" in page and "seer" in table(page, "board")
    assert "alice" not in table(page, "board")
    assert client.get("/boards/diverse/math", params={"lookahead": 3}).status_code == 404
    own = operator_browser(app).get(f"/submissions/{seer}").text
    assert "lookahead 10 (ranked on the lookahead-10 boards)" in own
    assert '<td data-role="rank">1<div class="muted small">of 1</div></td>' in own

    # the CLI over HTTP, and its exports
    from robobpp.cli import app as cli_app
    from robobpp.cli import register_commands
    from robobpp.client.api import ServerClient
    from robobpp.client.serve import BackgroundServer

    register_commands()
    cli = CliRunner()
    with BackgroundServer(app) as served:

        def run(*args: str) -> str:
            result = cli.invoke(cli_app, ["leaderboard", *args, "--server", served.url])
            assert result.exit_code == 0, result.output
            return result.stdout

        def rows(*args: str) -> list[dict[str, str]]:
            return list(csv.DictReader(io.StringIO(run(*args, "--format", "csv", "--view", "all"))))

        board_rows = rows("--dataset", "diverse", "--setting", "math", "--lookahead", "10")
        assert [(r["submission_id"], r["lookahead"], r["rank"]) for r in board_rows] == [
            (str(seer), "10", "1")
        ]
        assert {
            (r["submission_id"], r["lookahead"]) for r in rows("--dataset", "diverse", "--setting", "math")
        } == {
            (str(alice), "0"),
            (str(bob), "0"),
        }
        assert [(r["submission_id"], r["lookahead"]) for r in rows("--lookahead", "10")] == [
            (str(seer), "10")
        ]
        md = run("--dataset", "diverse", "--setting", "math", "--lookahead", "10", "--format", "md")
        assert md.startswith("**math/diverse · lookahead 10 · private track**") and "lookahead 10" in md
        shown = run("--dataset", "diverse", "--setting", "math", "--lookahead", "10")
        assert "lookahead 10" in shown and "seer" in shown and "alice" not in shown
        # the SDK reads a submission's standings on the boards of its lookahead
        with ServerClient(served.url, ADMIN) as api:
            standings = api.standings(api.submission(seer))
        assert {(s.rank, s.entries, s.lookahead) for s in standings} == {(1, 1, 10)}
        assert standings[0].board == "math/diverse (lookahead 10)"
        refused = cli.invoke(
            cli_app, ["leaderboard", "--lookahead", "10", "--protocol", "paper", "--server", served.url]
        )
        assert refused.exit_code != 0 and "lookahead 0 only" in refused.output

    # the last lookahead-10 entry leaves: its boards leave the publication, and the switch the pages
    with transaction(app.state.runtime.session_factory) as s:
        s.delete(s.get(Submission, seer))
    assert publisher(app).publish("private")
    assert client.get("/api/v1/leaderboards/diverse/math").json()["lookaheads"] == [0]
    assert client.get("/api/v1/leaderboards", params={"lookahead": 10}).status_code == 404
    assert 'data-role="lookahead"' not in client.get("/").text
    with app.state.runtime.read_session() as s:
        assert not s.execute(select(BoardPart.board).where(BoardPart.board.like("%lookahead%"))).first()
