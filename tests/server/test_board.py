"""Honest boards end to end, in process: real episodes (built-in policies and a garbage policy server),
the real work queue, the API and the pages; failed and partial entries are never ranked."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from robobpp.core import Action
from robobpp.db.models import Submission
from robobpp.server.app import create_app
from robobpp.server.bootstrap import bootstrap
from robobpp.server.config import Settings
from robobpp.sim.physics.config import PHYSICS_VERSION
from robobpp.worker.options import worker_options
from robobpp.worker.run import claim_and_run
from tests.server.conftest import submit_direct

GROUPS = 4
ADMIN = "board-admin-token-0123456789abcdef"


class NaNPolicy:
    """Answers garbage at step 0, like the issue's report."""

    name = "nan"

    def reset(self, *_: Any) -> None:
        return None

    def act(self, observation: Any) -> Action:
        return Action(float("nan"), 0.0, 0)


@pytest.fixture
def board_app(tmp_path: Path):
    settings = Settings(
        database_url=f"sqlite:///{tmp_path / 'board.sqlite3'}",
        state_dir=tmp_path,
        admin_token=ADMIN,
        workers=0,
        evaluate_baselines=False,
        settings=("math",),
        datasets=("diverse", "longboard"),
        groups=GROUPS,
        allow_private_policy_urls=True,
        board_refresh_s=0,
        spec_provider="robobpp.worker.specs:offline_spec",
    )
    app = create_app(settings, start_workers=False)
    bootstrap(app.state.runtime)
    with TestClient(app) as client:
        yield app, client
    app.state.runtime.dispose()


def submit(
    app: Any,
    participant: str,
    url: str,
    *,
    datasets: tuple[str, ...] = ("diverse", "longboard"),
    name: str | None = None,
) -> int:
    return submit_direct(app, participant, url, datasets=datasets, groups=GROUPS, name=name)


def drain(app: Any) -> None:
    runtime = app.state.runtime
    while claim_and_run(runtime.session_factory, worker_options(runtime.settings), "test:host:1") is not None:
        pass


def scores(client: TestClient, board: str = "diverse/math") -> dict[int, float]:
    data = client.get(f"/api/v1/leaderboards/{board}", params={"view": "all"}).json()
    return {e["submission_id"]: e["score"] for e in data["entries"]}


def test_garbage_policy_fails_is_unranked_and_moves_no_score(board_app, policy_server) -> None:
    app, client = board_app
    ids = [
        submit(app, "a", "builtin:dbl"),
        submit(app, "b", "builtin:random"),
        submit(app, "c", "builtin:hm"),
    ]
    drain(app)
    before = scores(client)
    assert set(before) == set(ids)

    garbage = policy_server(NaNPolicy, secret=None)
    bad = submit(app, "mallory", garbage.url)
    drain(app)
    with app.state.runtime.session() as s:
        sub = s.get(Submission, bad)
        assert sub.status == "failed" and "policy failure" in (sub.error or "")
    board = client.get("/api/v1/leaderboards/diverse/math", params={"view": "all"}).json()
    assert bad not in {e["submission_id"] for e in board["entries"]}
    (apart,) = board["unranked"]
    assert (
        apart["submission_id"] == bad
        and apart["status"] == "failed"
        and f"{GROUPS} of {GROUPS}" in apart["reason"]
    )
    assert scores(client) == before  # nobody's score moved
    grid = client.get("/api/v1/leaderboards", params={"view": "all"}).json()
    assert bad not in {r["submission_id"] for r in grid["rows"]}
    assert next(r for r in grid["apart"] if r["submission_id"] == bad)["status"] == "failed"
    page = client.get("/boards/diverse/math?view=all").text
    assert "Failed and partial entries" in page and "mallory" in page


def test_partial_submission_is_unranked_and_intervals_are_served(board_app) -> None:
    app, client = board_app
    full = [submit(app, "a", "builtin:dbl"), submit(app, "b", "builtin:random")]
    partial = submit(app, "p", "builtin:hm", datasets=("diverse",))
    drain(app)
    grid = client.get("/api/v1/leaderboards", params={"view": "all"}).json()
    assert {r["submission_id"] for r in grid["rows"]} == set(full)
    row = next(r for r in grid["apart"] if r["submission_id"] == partial)
    assert row["status"] == "partial" and row["mean"] is None and row["rank"] is None
    for r in grid["rows"]:
        assert r["mean_low"] <= r["mean"] <= r["mean_high"] and r["rank_low"] <= r["rank"] <= r["rank_high"]
    board = client.get("/api/v1/leaderboards/diverse/math", params={"view": "all"}).json()
    assert board["groups"] == GROUPS and board["ranked_by"] == "relative"
    for e in board["entries"]:
        assert e["score_low"] <= e["score"] + 1e-9 and e["score"] <= e["score_high"] + 1e-9
        lo, hi = e["intervals"]["space_utilization"]
        assert lo <= e["metrics"]["space_utilization"] <= hi
    home = client.get("/").text
    assert "Partial and failed submissions" in home and home.count('class="name method"') >= 3
    # an anonymous visitor may open none of these participants' pages, so none is linked
    assert 'href="/submissions/' not in home


def test_best_entry_per_participant_is_the_default_view(board_app) -> None:
    app, client = board_app
    a1 = submit(app, "alice", "builtin:random", name="alice-random")
    a2 = submit(app, "alice", "builtin:dbl", name="alice-dbl")
    b = submit(app, "bob", "builtin:random", name="bob-random")
    drain(app)
    everything = client.get("/api/v1/leaderboards/diverse/math", params={"view": "all"}).json()
    assert {e["submission_id"] for e in everything["entries"]} == {a1, a2, b}
    best = client.get("/api/v1/leaderboards/diverse/math").json()
    assert best["view"] == "best"
    alice = [e for e in best["entries"] if e["participant"] == "alice"]
    assert len(alice) == 1 and alice[0]["submission_id"] == a2  # DBL beats Random
    assert [e["rank"] for e in best["entries"]] == sorted(e["rank"] for e in best["entries"])
    assert max(e["rank_high"] for e in best["entries"]) <= 2  # ranked among the two participants
    one = client.get("/api/v1/leaderboards/diverse/math", params={"submission": a1, "limit": 1}).json()
    assert [e["submission_id"] for e in one["entries"]] == [a1]
    paged = client.get(
        "/api/v1/leaderboards/diverse/math", params={"view": "all", "limit": 1, "offset": 1}
    ).json()
    assert paged["total"] == 3 and len(paged["entries"]) == 1
    assert paged["entries"][0]["submission_id"] == everything["entries"][1]["submission_id"]


def test_metrics_endpoint_counts_the_queue(board_app) -> None:
    app, client = board_app
    submit(app, "a", "builtin:dbl")
    text = client.get("/metrics", headers={"Authorization": f"Bearer {ADMIN}"}).text
    assert f'robobpp_episodes{{status="pending"}} {float(2 * GROUPS)}' in text
    drain(app)
    text = client.get("/metrics", headers={"Authorization": f"Bearer {ADMIN}"}).text
    assert 'robobpp_episodes{status="pending"} 0.0' in text
    assert 'robobpp_submissions{status="completed"} 1.0' in text


def test_stable_score_does_not_move_when_entries_arrive(board_app) -> None:
    app, client = board_app
    first = submit(app, "a", "builtin:random")
    drain(app)
    (alone,) = client.get("/api/v1/leaderboards/diverse/math").json()["entries"]
    submit(app, "b", "builtin:dbl")
    drain(app)
    board = client.get("/api/v1/leaderboards/diverse/math").json()
    again = next(e for e in board["entries"] if e["submission_id"] == first)
    assert math.isclose(again["stable"], alone["stable"]) and again["stable_low"] == alone["stable_low"]
    assert np.isfinite(again["stable"])


def test_public_track_carries_the_baselines(board_app) -> None:
    from robobpp.server.bootstrap import ensure_baselines

    app, _client = board_app
    baselines = ("dbl", "random")
    settings = app.state.runtime.settings.model_copy(update={"baselines": baselines})
    with app.state.runtime.session() as s:
        created = ensure_baselines(s, settings)
        again = ensure_baselines(s, settings)  # idempotent
        tracks = s.execute(select(Submission.track, Submission.policy_url)).all()
    assert created == 2 * len(baselines) and again == 0
    assert (
        {u for t, u in tracks if t == "public"}
        == {u for t, u in tracks if t == "private"}
        == {f"builtin:{b}" for b in baselines}
    )


def test_stale_baselines_are_queued_again(tmp_path: Path) -> None:
    """An upgraded deployment: a baseline evaluated under an older physics version, or before the paper protocol
    existed, or before a setting was offered, is queued again at start; a current one is not."""
    from sqlalchemy import delete, update

    from robobpp.db.models import EpisodeRow, RunRow
    from robobpp.server.bootstrap import ensure_baselines

    def configured(*offered: str) -> Settings:
        return Settings(
            database_url=f"sqlite:///{tmp_path / 'stale.sqlite3'}",
            state_dir=tmp_path,
            admin_token=ADMIN,
            workers=0,
            evaluate_baselines=False,
            settings=offered,
            datasets=("diverse",),
            groups=GROUPS,
            baselines=("dbl", "lsah", "hm", "random"),
            public_baselines=False,
            spec_provider="robobpp.worker.specs:offline_spec",
        )

    settings = configured("math", "physics")
    app = create_app(settings, start_workers=False)
    bootstrap(app.state.runtime)
    try:
        with app.state.runtime.session() as s:
            assert ensure_baselines(s, settings) == 4
            ids = {sub.policy_url: sub.id for sub in s.execute(select(Submission)).scalars()}
            # every one "finished": its episodes done under the current physics
            s.execute(update(Submission).values(status="completed"))
            s.execute(update(EpisodeRow).values(status="done"))
            s.execute(
                update(EpisodeRow)
                .where(EpisodeRow.setting == "physics")
                .values(physics_version=PHYSICS_VERSION)
            )
            old_physics = ids["builtin:dbl"]
            s.execute(
                update(EpisodeRow)
                .where(EpisodeRow.submission_id == old_physics, EpisodeRow.setting == "physics")
                .values(physics_version="3")
            )
            no_paper = ids["builtin:lsah"]
            s.execute(delete(RunRow).where(RunRow.submission_id == no_paper, RunRow.protocol == "paper"))
            s.execute(update(Submission).where(Submission.id == ids["builtin:hm"]).values(status="failed"))
        with app.state.runtime.session() as s:
            assert ensure_baselines(s, settings) == 2
            queued = s.execute(
                select(Submission.policy_url).where(Submission.status == "queued").order_by(Submission.id)
            ).scalars()
            assert list(queued) == ["builtin:dbl", "builtin:lsah"]
            assert ensure_baselines(s, settings) == 0  # the new ones are running: nothing more
        # a setting offered since: every completed baseline lacks it
        wider = configured("math", "physics", "execution")
        with app.state.runtime.session() as s:
            s.execute(update(Submission).values(status="completed"))
            s.execute(update(EpisodeRow).values(status="done"))
            s.execute(
                update(EpisodeRow)
                .where(EpisodeRow.setting == "physics")
                .values(physics_version=PHYSICS_VERSION)
            )
            assert ensure_baselines(s, wider) == 4
    finally:
        app.state.runtime.dispose()
