"""The JSON API on bad input: clear RFC 9457 problems (4xx), and nothing half-written in the database."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from robobpp.db.models import EpisodeRow, RunRow, Submission
from robobpp.server.app import create_app
from robobpp.server.config import Settings
from tests.server.conftest import ADMIN_TOKEN, OFFLINE, free_port

ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}


def make_settings(db_url: str, tmp_path, **kw) -> Settings:
    base = {
        "database_url": db_url,
        "state_dir": tmp_path,
        "admin_token": ADMIN_TOKEN,
        "workers": 0,
        "spec_provider": OFFLINE,
        "board_refresh_s": 0,
        "groups": 2,
        "settings": ("math",),
        "evaluate_baselines": False,
        "allow_private_policy_urls": True,
        "quota_concurrent": 2,
        "quota_submissions_per_day": 3,
    }
    return Settings(**{**base, **kw})


@pytest.fixture
def api(db_url: str, tmp_path) -> Iterator[TestClient]:
    app = create_app(make_settings(db_url, tmp_path))
    with TestClient(app) as client:
        yield client


def participant(api: TestClient, name: str) -> dict[str, str]:
    r = api.post("/api/v1/participants", json={"name": name}, headers=ADMIN)
    assert r.status_code == 201, r.text
    return {"Authorization": f"Bearer {r.json()['token']}"}


def row_counts(api: TestClient) -> tuple[int, int, int]:
    with api.app.state.runtime.session() as s:  # type: ignore[attr-defined]
        return tuple(
            s.execute(select(func.count()).select_from(t)).scalar_one()
            for t in (Submission, RunRow, EpisodeRow)
        )


def assert_problem(r, status: int, kind: str | None = None) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    body = r.json()
    assert (
        body["status"] == status and body["title"] and body["detail"] and body["type"].startswith("https://")
    )
    if kind:
        assert body["type"].endswith("/" + kind), body
    return body


def test_bad_submissions_get_clear_problems_and_write_nothing(api: TestClient, policy_server) -> None:
    alice = participant(api, "alice")
    good = {"name": "ok", "policy_url": policy_server(secret=None).url, "datasets": ["diverse"]}
    before = row_counts(api)
    cases = [
        (b"{not json", 400, "malformed-json"),
        (b"[]", 422, "validation-error"),
        (b'{"name": 5, "policy_url": "http://x"}', 422, "validation-error"),
        (b'{"name": "a", "policy_url": "http://x", "surprise": 1}', 422, "validation-error"),
        (b'{"name": "a", "policy_url": "http://x", "datasets": ["moon"]}', 422, "validation-error"),
        (b'{"name": "a", "policy_url": "http://x", "lookahead": 1e309}', 422, "validation-error"),
        (b'{"name": "a", "policy_url": "ftp://x"}', 422, "policy-url-invalid"),
        (b'{"name": "a", "policy_url": "builtin:dbl"}', 422, "policy-url-invalid"),
        (
            f'{{"name": "a", "policy_url": "http://127.0.0.1:{free_port()}"}}'.encode(),
            422,
            "policy-unreachable",
        ),
        (b'{"name": "a", "policy_url": "http://169.254.169.254"}', 422, "policy-url-forbidden"),
        (b'{"name": "a", "policy_url": "http://nowhere.invalid"}', 422, "policy-unreachable"),
        (b'{"name": "a", "policy_url": "http://x", "settings": ["execution"]}', 422, "setting-unavailable"),
        (b'{"name": "' + b"a" * 100_000 + b'"}', 413, "body-too-large"),
    ]
    for body, status, kind in cases:
        r = api.post(
            "/api/v1/submissions", content=body, headers={**alice, "content-type": "application/json"}
        )
        assert_problem(r, status, kind)
    assert row_counts(api) == before
    wrong_secret = {
        **good,
        "policy_url": policy_server(secret="the-real-secret").url,
        "secret": "a-wrong-secret",
    }
    assert_problem(api.post("/api/v1/submissions", json=wrong_secret, headers=alice), 422, "policy-signature")
    assert row_counts(api) == before
    r = api.post("/api/v1/submissions", json=good, headers=alice)
    assert r.status_code == 201, r.text
    assert row_counts(api) == (before[0] + 1, before[1] + 1, before[2] + 2)


def test_a_signature_mismatch_says_which_side_and_what_to_do(api: TestClient, policy_server) -> None:
    """A policy that answers but under another secret was reported as "Policy unreachable": it is a
    signature mismatch, named as such, with what to change on which side."""
    alice = participant(api, "alice")
    signed, unsigned = policy_server(secret="the-real-secret").url, policy_server(secret=None).url
    cases = [
        ({"policy_url": signed, "secret": "a-wrong-secret"}, "refused this submission's signature"),
        ({"policy_url": signed}, "requires signed requests, and this submission has no secret"),
        (
            {"policy_url": unsigned, "secret": "a-wrong-secret"},
            "start the policy server with the same secret",
        ),
    ]
    for fields, advice in cases:
        r = api.post("/api/v1/submissions", json={"name": "s", **fields}, headers=alice)
        body = assert_problem(r, 422, "policy-signature")
        assert body["title"] == "Signature mismatch" and "unreachable" not in body["detail"]
        assert advice in body["detail"] and "robobpp protocol check" in body["detail"], body["detail"]


def test_tokens_and_ownership(api: TestClient, policy_server) -> None:
    assert_problem(api.get("/api/v1/me"), 401, "unauthorized")
    assert_problem(api.get("/api/v1/me", headers={"Authorization": "Bearer nope"}), 401)
    assert_problem(api.get("/api/v1/me", headers={"Authorization": "Bearer " + "x" * 5000}), 401)
    alice, bob = participant(api, "alice"), participant(api, "bob")
    assert_problem(api.post("/api/v1/participants", json={"name": "carol"}, headers=alice), 403, "forbidden")
    assert_problem(api.post("/api/v1/participants", json={"name": "alice"}, headers=ADMIN), 409, "conflict")
    url = policy_server(secret=None).url
    sid = api.post("/api/v1/submissions", json={"name": "a", "policy_url": url}, headers=alice).json()["id"]
    for path in (f"/api/v1/submissions/{sid}", f"/api/v1/submissions/{sid}/episodes"):
        assert api.get(path, headers=alice).status_code == 200
        assert_problem(api.get(path, headers=bob), 404, "not-found")  # same answer as a missing id
    assert_problem(api.post(f"/api/v1/submissions/{sid}/cancel", headers=bob), 404)
    assert_problem(api.get("/api/v1/submissions/999999", headers=alice), 404)
    assert_problem(api.get("/api/v1/submissions/99999999999999999999", headers=alice), 422)
    assert api.get("/api/v1/submissions", headers=bob).json() == []
    me = api.get("/api/v1/me", headers=alice).json()
    assert me["participant"]["name"] == "alice" and me["quota"]["active"] == 1
    # tokens are stored hashed: the token text appears nowhere in the database
    with api.app.state.runtime.session() as s:  # type: ignore[attr-defined]
        from robobpp.db.models import ApiToken

        hashes = s.execute(select(ApiToken.token_hash)).scalars().all()
    assert all(len(h) == 64 and alice["Authorization"][7:] != h for h in hashes)


def test_quotas(api: TestClient, policy_server) -> None:
    alice = participant(api, "alice")
    body = {"name": "q", "policy_url": policy_server(secret=None).url, "datasets": ["diverse"]}
    ids = [api.post("/api/v1/submissions", json=body, headers=alice).json()["id"] for _ in range(2)]
    assert_problem(
        api.post("/api/v1/submissions", json=body, headers=alice), 429, "quota-exceeded"
    )  # concurrent
    api.post(f"/api/v1/submissions/{ids[0]}/cancel", headers=alice)
    assert api.post("/api/v1/submissions", json=body, headers=alice).status_code == 201
    api.post(f"/api/v1/submissions/{ids[1]}/cancel", headers=alice)
    assert_problem(
        api.post("/api/v1/submissions", json=body, headers=alice), 429, "quota-exceeded"
    )  # per day


def test_health_metrics_docs_and_boards(api: TestClient) -> None:
    assert api.get("/healthz").json()["database"] == "ok"
    assert api.get("/metrics").status_code == 401  # the operator's (ROBOBPP_METRICS_PUBLIC opens it)
    assert "robobpp_episodes" in api.get("/metrics", headers=ADMIN).text
    assert api.get("/docs").status_code == 200
    assert "/api/v1/submissions" in api.get("/openapi.json").json()["paths"]
    board = api.get("/api/v1/leaderboards/diverse/math").json()
    assert board["entries"] == [] and board["weights"]["space_utilization"] == 0.6
    assert_problem(api.get("/api/v1/leaderboards/moon/math"), 422)
    assert_problem(api.get("/api/v1/nothing-here"), 404)
    assert_problem(api.delete("/api/v1/leaderboards"), 405)


def test_settings_refuse_default_secrets_outside_dev(tmp_path) -> None:
    for token in (None, "changeme", "short"):
        with pytest.raises(ValueError, match="ROBOBPP_ADMIN_TOKEN"):
            Settings(env="prod", admin_token=token, state_dir=tmp_path)
    with pytest.raises(ValueError, match="dev only"):
        Settings(env="prod", admin_token="x" * 32, allow_private_policy_urls=True)
    assert Settings(env="prod", admin_token="x" * 32).env == "prod"
    dev = Settings(state_dir=tmp_path)
    assert len(dev.effective_admin_token) >= 32 and (tmp_path / "admin_token").stat().st_mode & 0o077 == 0


def test_a_submission_without_a_name_is_named_after_its_policys_info(api: TestClient) -> None:
    """`robobpp submit URL` named the submission after its URL ("127.0.0.1-29317"): without a name it takes
    the policy's /info name and version, as `robobpp evaluate` labels it; a given name still wins."""
    from robobpp.client.serve import BackgroundServer, create_policy_app
    from robobpp.policies.dbl import DBL

    alice = participant(api, "alice")
    with BackgroundServer(create_policy_app(DBL, None, name="lowest-first", version="1.2")) as srv:
        named = api.post("/api/v1/submissions", json={"policy_url": srv.url}, headers=alice)
        assert named.status_code == 201, named.text
        assert named.json()["name"] == "lowest-first 1.2"
        given = api.post("/api/v1/submissions", json={"name": "mine", "policy_url": srv.url}, headers=alice)
        assert given.status_code == 201 and given.json()["name"] == "mine"
