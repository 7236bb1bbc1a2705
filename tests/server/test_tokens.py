"""Token revocation (owner or admin; effective at once) and the Prometheus route label (full path)."""

from __future__ import annotations

import re
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from robobpp.server.app import create_app
from tests.server.test_api import ADMIN, assert_problem, make_settings


@pytest.fixture
def api(db_url: str, tmp_path) -> Iterator[TestClient]:
    """The API in-process, on SQLite and on PostgreSQL (revocation takes a row lock)."""
    with TestClient(create_app(make_settings(db_url, tmp_path))) as client:
        yield client


def _new(api: TestClient, name: str) -> tuple[dict[str, str], int, int]:
    """(auth header, token id, participant id) of a new participant."""
    body = api.post("/api/v1/participants", json={"name": name}, headers=ADMIN).json()
    return {"Authorization": f"Bearer {body['token']}"}, body["id"], body["participant"]["id"]


def test_owner_revokes_a_token_and_it_stops_working_at_once(api: TestClient) -> None:
    alice, first_id, alice_pid = _new(api, "alice")
    second = api.post(f"/api/v1/participants/{alice_pid}/tokens", headers=ADMIN).json()
    alice2 = {"Authorization": f"Bearer {second['token']}"}
    listed = api.get("/api/v1/tokens", headers=alice).json()
    assert [t["id"] for t in listed] == [first_id, second["id"]]
    assert all(t["revoked_at"] is None and "token" not in t for t in listed)

    r = api.delete(f"/api/v1/tokens/{first_id}", headers=alice2)
    assert r.status_code == 200, r.text
    revoked_at = r.json()["revoked_at"]
    assert revoked_at is not None
    body = assert_problem(api.get("/api/v1/me", headers=alice), 401, "unauthorized")
    assert "revoked" in body["detail"]
    assert api.get("/api/v1/me", headers=alice2).json()["participant"]["name"] == "alice"
    # idempotent: the first revocation time is kept
    assert api.delete(f"/api/v1/tokens/{first_id}", headers=alice2).json()["revoked_at"] == revoked_at
    # a participant may revoke the very token it calls with
    assert api.delete(f"/api/v1/tokens/{second['id']}", headers=alice2).status_code == 200
    assert_problem(api.get("/api/v1/me", headers=alice2), 401)


def test_only_the_owner_or_the_admin_may_revoke(api: TestClient) -> None:
    alice, alice_token, _ = _new(api, "alice")
    bob, bob_token, bob_pid = _new(api, "bob")
    # another participant's token looks exactly like a missing one
    missing = assert_problem(api.delete("/api/v1/tokens/999999", headers=alice), 404, "not-found")
    other = assert_problem(api.delete(f"/api/v1/tokens/{bob_token}", headers=alice), 404, "not-found")
    assert other["title"] == missing["title"]
    assert [t["id"] for t in api.get("/api/v1/tokens", headers=alice).json()] == [alice_token]
    assert api.get("/api/v1/me", headers=bob).status_code == 200
    assert_problem(api.delete(f"/api/v1/tokens/{bob_token}"), 401)
    assert_problem(api.delete("/api/v1/tokens/0", headers=alice), 422)
    assert_problem(api.delete("/api/v1/tokens/99999999999999999999", headers=alice), 422)

    # the admin sees every token, filters by participant, and revokes anyone's
    assert {t["id"] for t in api.get("/api/v1/tokens", headers=ADMIN).json()} == {alice_token, bob_token}
    only_bob = api.get("/api/v1/tokens", params={"participant_id": bob_pid}, headers=ADMIN).json()
    assert [t["id"] for t in only_bob] == [bob_token]
    assert api.delete(f"/api/v1/tokens/{bob_token}", headers=ADMIN).status_code == 200
    assert_problem(api.get("/api/v1/me", headers=bob), 401)
    assert api.get("/api/v1/me", headers=alice).status_code == 200


def test_metrics_route_label_is_the_full_path_template(api: TestClient) -> None:
    alice, _, _ = _new(api, "alice")
    api.get("/api/v1/leaderboards/diverse/math")
    api.get("/api/v1/submissions/12345", headers=alice)
    api.get("/api/v1/nothing-here")
    text = api.get("/metrics", headers=ADMIN).text
    routes = set(re.findall(r'robobpp_http_requests_total\{method="[A-Z]+",route="([^"]*)"', text))
    assert "/api/v1/leaderboards/{dataset}/{setting}" in routes
    assert "/api/v1/submissions/{submission_id}" in routes  # a template, not the id the client sent
    assert "/api/v1/participants" in routes
    assert "unmatched" in routes
    assert not any(r.startswith(("/leaderboards", "/submissions", "/participants")) for r in routes)
