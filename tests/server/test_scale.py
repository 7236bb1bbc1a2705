"""The board at scale, on SQLite and PostgreSQL: a finished run reaches every cached route, finished
submissions' cached forms follow a verification verdict, and a /metrics scrape costs the same however much
history the database holds (how boards are published: test_board_publishing.py).

(Latencies are measured by bench/bench_server.py, never asserted here.)"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import event, select

from robobpp.boards.worker import BoardPublisher, BoardWorker
from robobpp.db.models import Participant, Submission
from robobpp.server.app import create_app
from robobpp.server.bootstrap import bootstrap
from robobpp.server.config import Settings
from robobpp.worker.options import worker_options
from robobpp.worker.run import claim_and_run
from tests.server.conftest import submit_direct

GROUPS = 3
ADMIN = "scale-admin-token-0123456789abcdef"
DATASETS = ("diverse", "longboard")


def make_app(url: str, tmp_path: Path, **extra: Any) -> Any:
    settings = Settings(
        database_url=url,
        state_dir=tmp_path,
        admin_token=ADMIN,
        workers=0,
        evaluate_baselines=False,
        settings=("math",),
        datasets=DATASETS,
        groups=GROUPS,
        board_refresh_s=0,
        spec_provider="robobpp.worker.specs:offline_spec",
        **extra,
    )
    app = create_app(settings, start_workers=False)
    bootstrap(app.state.runtime)
    return app


@pytest.fixture
def scale_app(db_url: str, tmp_path: Path):
    app = make_app(db_url, tmp_path)
    with TestClient(app, headers={"Authorization": f"Bearer {ADMIN}"}) as client:
        yield app, client
    app.state.runtime.dispose()


def submit(app: Any, participant: str, url: str, name: str | None = None) -> int:
    return submit_direct(app, participant, url, datasets=DATASETS, groups=GROUPS, name=name)


def drain(app: Any) -> None:
    runtime = app.state.runtime
    while claim_and_run(runtime.session_factory, worker_options(runtime.settings), "test:host:1") is not None:
        pass


def operator_browser(app: Any) -> TestClient:
    """A browser signed in as the operator, through the sign-in form."""
    import re

    browser = TestClient(app)
    csrf = re.search(r'name="csrf" value="([^"]+)"', browser.get("/sign-in").text)
    assert csrf is not None
    browser.post("/sign-in", data={"token": ADMIN, "csrf": csrf.group(1)})
    return browser


def test_a_finished_run_reaches_every_cached_route(scale_app) -> None:
    app, client = scale_app
    submit(app, "alice", "builtin:random", name="first-entry")
    drain(app)
    routes = [
        "/api/v1/leaderboards/diverse/math?view=all",
        "/api/v1/leaderboards?view=all",
        "/",
        "/boards/diverse/math?view=all",
    ]
    anonymous = TestClient(app)
    for path in routes:  # cached now (the pages as an anonymous visitor sees them: shared)
        body = (anonymous if not path.startswith("/api") else client).get(path).text
        assert "first-entry" in body and "second-entry" not in body, path
    submit(app, "bob", "builtin:dbl", name="second-entry")
    drain(app)
    for path in routes:
        body = (anonymous if not path.startswith("/api") else client).get(path).text
        assert "first-entry" in body and "second-entry" in body, path


def test_best_entry_default_and_pages_of_all_entries(scale_app) -> None:
    app, client = scale_app
    for name, url in (("r", "builtin:random"), ("d", "builtin:dbl"), ("l", "builtin:lsah")):
        submit(app, "alice", url, name=name)
    submit(app, "bob", "builtin:random", name="bob-r")
    drain(app)
    best = client.get("/api/v1/leaderboards/diverse/math").json()
    assert best["view"] == "best" and best["total"] == 2  # one entry per participant
    assert sorted(e["participant"] for e in best["entries"]) == ["alice", "bob"]
    everything = client.get("/api/v1/leaderboards/diverse/math", params={"view": "all"}).json()
    assert everything["total"] == 4
    pages = [
        client.get(
            "/api/v1/leaderboards/diverse/math", params={"view": "all", "limit": 3, "offset": o}
        ).json()["entries"]
        for o in (0, 3)
    ]
    assert [len(p) for p in pages] == [3, 1]
    assert [e["submission_id"] for p in pages for e in p] == [
        e["submission_id"] for e in everything["entries"]
    ]
    grid = client.get("/api/v1/leaderboards", params={"limit": 1}).json()
    assert grid["total"] == 2 and len(grid["rows"]) == 1


def test_a_finished_submission_s_cached_forms_follow_its_verdict(scale_app) -> None:
    app, client = scale_app
    sid = submit(app, "alice", "builtin:dbl")
    drain(app)
    first = client.get(f"/api/v1/submissions/{sid}").json()
    listed = client.get("/api/v1/submissions").json()
    assert first["status"] == "completed" and first["verification"] is None
    assert [s for s in listed if s["id"] == sid] == [first]
    assert len(client.get(f"/api/v1/submissions/{sid}/episodes").json()) == GROUPS * len(DATASETS)
    with app.state.runtime.session() as s:
        s.get(Submission, sid).verification = {"status": "verified", "submission_id": 99}
    again = client.get(f"/api/v1/submissions/{sid}").json()
    assert again["verification"] == {"status": "verified", "submission_id": 99}
    assert [s["verification"] for s in client.get("/api/v1/submissions").json() if s["id"] == sid] == [
        again["verification"]
    ]


def _statements(app: Any, client: TestClient) -> list[str]:
    seen: list[str] = []
    engine = app.state.runtime.read_engine

    def record(_conn: Any, _cursor: Any, statement: str, *_: Any) -> None:
        text = " ".join(statement.split()).lower()
        if text.startswith("select"):  # not SQLite's BEGIN
            seen.append(text)

    event.listen(engine, "before_cursor_execute", record)
    try:
        assert client.get("/metrics", headers={"Authorization": f"Bearer {ADMIN}"}).status_code == 200
    finally:
        event.remove(engine, "before_cursor_execute", record)
    return seen


@pytest.fixture
def quiet_scale_app(db_url: str, tmp_path: Path):
    """As ``scale_app`` but without a board worker polling the database beside the statements counted."""
    app = make_app(db_url, tmp_path, board_worker="off", board_wait_s=0)
    with TestClient(app, headers={"Authorization": f"Bearer {ADMIN}"}) as client:
        yield app, client
    app.state.runtime.dispose()


def test_metrics_scrape_costs_the_same_with_more_history(quiet_scale_app) -> None:
    app, client = quiet_scale_app
    BoardWorker(
        BoardPublisher(app.state.runtime.read_session, app.state.runtime.session, DATASETS, ("math",))
    ).run_once()
    submit(app, "alice", "builtin:random")
    drain(app)
    _statements(app, client)  # the first scrape counts finished submissions once
    small = _statements(app, client)
    for who in ("bob", "carol", "dave"):
        submit(app, who, "builtin:dbl")
    drain(app)
    after_finish = _statements(app, client)
    large = _statements(app, client)
    # nothing finished since the last scrape: the same statements, all index lookups, none aggregating
    # the finished history (episodes or submissions)
    assert large == small
    assert not any("group by" in s for s in large), large
    assert all(" where " in s for s in large), large
    # something finished: its counts are read once more, then cached again
    assert len(after_finish) > len(large)
    text = client.get("/metrics", headers={"Authorization": f"Bearer {ADMIN}"}).text
    assert 'robobpp_submissions{status="completed"} 4.0' in text
    assert 'robobpp_submissions{status="queued"} 0.0' in text
    assert 'robobpp_episodes{status="pending"} 0.0' in text
    assert 'robobpp_board_version{track="private"}' in text
    assert 'robobpp_board_publication_seconds{track="private"}' in text


@pytest.mark.parametrize("page", ["account", "operator-participant"])
def test_pages_listing_submissions_are_paged(scale_app, monkeypatch: pytest.MonkeyPatch, page: str) -> None:

    from robobpp.server.site import account

    app, _client = scale_app
    names = [f"entry-{i}" for i in range(3)]
    for name in names:
        submit(app, "alice", "builtin:random", name=name)
    submit(app, "bob", "builtin:random", name="someone-else")  # on the operator's account page only
    drain(app)
    monkeypatch.setattr(account, "ACCOUNT_PAGE_SIZE", 2)
    if page == "account":
        names.append("someone-else")
        path = "/account"
    else:
        with app.state.runtime.read_session() as s:
            alice = s.execute(select(Participant.id).where(Participant.name == "alice")).scalar_one()
        path = f"/operator/participants/{alice}"
    browser = operator_browser(app)
    first, second = browser.get(path).text, browser.get(path, params={"page": 2}).text
    assert [n for n in names if n in first] == names[-2:]  # newest first
    assert 'href="?page=2"' in first and 'href="?page=1"' not in first
    assert [n for n in names if n in second] == names[-4:-2]
    assert ('href="?page=3"' in second) == (len(names) > 4) and 'href="?page=1"' in second


def test_a_waiting_submission_is_listed_from_its_form_until_an_episode_moves(
    scale_app, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A page listing a backlog of queued submissions builds each once, then again only when one of its
    episodes changes status: never a stale progress, never a rebuild per read."""
    from robobpp.db import queries

    app, client = scale_app
    sid = submit(app, "alice", "builtin:random", name="waiting")
    built: list[int] = []
    view = queries.submission_view

    def counted_view(s: Any, sub: Any, *a: Any) -> Any:
        built.append(sub.id)
        return view(s, sub, *a)

    monkeypatch.setattr(queries, "submission_view", counted_view)

    def listed() -> dict[str, Any]:
        return next(s for s in client.get("/api/v1/submissions").json() if s["id"] == sid)

    first = listed()
    assert first["status"] == "queued" and first["progress"]["episodes_done"] == 0
    assert first["progress"]["phase"] == "math/diverse"
    assert listed() == first and built == [sid]  # the second read built nothing
    runtime = app.state.runtime
    assert claim_and_run(runtime.session_factory, worker_options(runtime.settings), "test:host:1") is not None
    moved = listed()
    assert built == [sid, sid]
    assert moved["status"] == "running" and moved["progress"]["episodes_done"] == 1
    drain(app)
    done = listed()
    assert done["status"] == "completed" and done["progress"]["phase"] is None
    assert done["progress"]["episodes_done"] == done["progress"]["episodes_total"] == len(DATASETS) * GROUPS


def test_the_operator_page_counts_follow_submissions_and_revoked_tokens(scale_app) -> None:
    """The participants table is kept per version of what it counts: a new submission or a revoked token
    shows at the next view, and nothing else rebuilds it."""
    import re

    app, client = scale_app
    token = client.post("/api/v1/participants", json={"name": "carol"}).json()
    browser = operator_browser(app)

    def carol() -> tuple[int, int]:
        row = re.search(r">carol</a></td>\s*<td>(\d+)</td><td>(\d+)</td>", browser.get("/operator").text)
        assert row is not None
        return int(row.group(1)), int(row.group(2))

    assert carol() == (1, 0)
    kept = app.state.operator_rows
    assert carol() == (1, 0) and app.state.operator_rows is kept  # nothing changed: not read again
    submit(app, "carol", "builtin:random")
    assert carol() == (1, 1)
    assert client.delete(f"/api/v1/tokens/{token['id']}").status_code == 200
    assert carol() == (0, 1)
