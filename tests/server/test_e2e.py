"""End to end, on SQLite and on the machine's PostgreSQL: a real ``robobpp serve``, a policy served with
the SDK, a submission, and the leaderboard entry compared with the same episodes run locally."""

from __future__ import annotations

import httpx
import pytest

from robobpp.episode import run_episode
from robobpp.policies.dbl import DBL
from robobpp.scoring.metrics import aggregate
from robobpp.worker.specs import offline_spec
from tests.server.conftest import new_participant, wait_for

GROUPS = 2


def local_figures(dataset: str, setting: str, split: str) -> dict[str, float | None]:
    episodes = []
    for g in range(GROUPS):
        result = run_episode(offline_spec(dataset, split, g, GROUPS), DBL(), setting)
        episodes.append({**result.metrics, **result.counters})
    return aggregate(episodes, setting)


def test_submit_remote_policy_and_read_the_leaderboard(db_url, make_server, policy_server) -> None:
    server = make_server(db_url)
    policy = policy_server(DBL, secret="policy-secret-123")
    admin = server.client()
    alice = server.client(new_participant(admin, "alice"))

    r = alice.post(
        "/submissions",
        json={
            "name": "my dbl",
            "policy_url": policy.url,
            "secret": "policy-secret-123",
            "datasets": ["diverse"],
            "settings": ["math"],
        },
    )
    assert r.status_code == 201, r.text
    sub = r.json()
    assert sub["progress"]["episodes_total"] == GROUPS
    assert "secret" not in sub

    done = wait_for(
        lambda: (s := alice.get(f"/submissions/{sub['id']}").json())["status"] == "completed" and s
    )
    assert done["progress"]["episodes_done"] == GROUPS

    board = alice.get("/leaderboards/diverse/math").json()
    mine = next(e for e in board["entries"] if e["submission_id"] == sub["id"])
    expected = local_figures("diverse", "math", "test")
    for key in ("space_utilization", "occupancy"):
        assert mine["metrics"][key] == pytest.approx(expected[key], rel=1e-12)
    assert mine["metrics"]["decision_time"] > 0
    assert set(mine["normalized"]) == {"space_utilization", "occupancy", "decision_time"}

    # The built-in DBL baseline, served over robobpp/1 by the worker itself: same geometry as the remote DBL.
    baseline = wait_for(
        lambda: next(
            (e for e in alice.get("/leaderboards/diverse/math").json()["entries"] if e["baseline"]), None
        )
    )
    assert baseline["metrics"]["space_utilization"] == pytest.approx(mine["metrics"]["space_utilization"])
    assert {e["rank"] for e in alice.get("/leaderboards/diverse/math").json()["entries"]} <= {1, 2}

    episodes = alice.get(f"/submissions/{sub['id']}/episodes").json()
    assert len(episodes) == GROUPS
    assert all(e["status"] == "done" and e["termination"] and e["attempts"] == 1 for e in episodes)
    detail = alice.get(f"/submissions/{sub['id']}/episodes/{episodes[0]['id']}").json()
    assert detail["trace"] is None  # private track: no replay

    grid = alice.get("/leaderboards", params={"view": "all"}).json()
    row = next(row for row in grid["rows"] + grid["apart"] if row["submission_id"] == sub["id"])
    assert "math/diverse" in row["cells"]
    # one board of several: partial, listed apart, no Mean (the Mean ranks complete entries only)
    assert grid["boards"] == 1 or (row["status"] == "partial" and row["mean"] is None)

    # The policy secret never leaves the server: not in any answer, not in the log, not on the pages.
    answers = [
        alice.get(f"/submissions/{sub['id']}"),
        alice.get(f"/submissions/{sub['id']}/episodes"),
        httpx.get(f"{server.url}/submissions/{sub['id']}"),
        httpx.get(f"{server.url}/"),
    ]
    # the submission's page is its owner's only: anonymous visitors get a 404 (server/pages.py)
    assert [a.status_code for a in answers] == [200, 200, 404, 200]
    assert all("policy-secret-123" not in a.text for a in answers)
    assert "policy-secret-123" not in server.log.read_text()


def test_public_track_keeps_traces(make_server, policy_server, tmp_path) -> None:
    server = make_server(f"sqlite:///{tmp_path / 'pub.sqlite3'}", ROBOBPP_EVALUATE_BASELINES="0")
    policy = policy_server(DBL, secret=None)
    alice = server.client(new_participant(server.client(), "bob"))
    r = alice.post(
        "/submissions",
        json={
            "name": "pub",
            "policy_url": policy.url,
            "track": "public",
            "datasets": ["longboard"],
            "settings": ["math"],
        },
    )
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    wait_for(lambda: alice.get(f"/submissions/{sid}").json()["status"] == "completed")
    ep = alice.get(f"/submissions/{sid}/episodes").json()[0]
    detail = alice.get(f"/submissions/{sid}/episodes/{ep['id']}").json()
    assert detail["trace"]["steps"] and detail["trace"]["steps"][0]["action"] is not None
    board = alice.get("/leaderboards/longboard/math", params={"track": "public"}).json()
    expected = local_figures("longboard", "math", "train")
    assert board["entries"][0]["metrics"]["space_utilization"] == pytest.approx(expected["space_utilization"])
