"""Who sees what: a submission's details, live status and failure reasons belong to its owner and the
operator, on every page and every API route; policy-supplied text is escaped and cut everywhere.

One app (SQLite, no workers), four viewers: anonymous, the owner (alice), another participant (bob), the
operator. Alice's episodes carry a hostile termination detail — a script tag, a direction override, a
private box size echoed back by a "policy" and a tail past the cut — written straight into the database,
as a worker would write a policy's HTTP 500 body.
"""

from __future__ import annotations

import base64
import re
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from robobpp.core import Box, ContainerSpec, EpisodeSpec
from robobpp.db import work
from robobpp.db.models import EpisodeRow, Participant, Submission, utcnow
from robobpp.db.queries import SHOWN_TEXT_LIMIT
from robobpp.episode import run_episode
from robobpp.policies import load_policy
from robobpp.provenance import recorded_rules
from robobpp.server import pages
from robobpp.server.app import create_app
from robobpp.server.site.account import PULL_OFFERED
from tests.server.conftest import ADMIN_TOKEN
from tests.server.test_api import make_settings

#: What a policy answering HTTP 500 with the box it was just shown leaves in termination_detail.
LEAK = "37.125"
TAIL = "TAIL-SENTINEL"
DETAIL = (
    f'POST /act (step 0) failed with HTTP 500: \'{{"box": {{"length": {LEAK}}}}}\' '
    "<script>alert('x')</script>\u202e" + "A" * 900 + TAIL
)
POLICY_URL = "http://10.1.2.3:9000/alice-only-path"
VIEWERS = ("anonymous", "owner", "other", "operator")


@dataclass
class World:
    clients: dict[str, TestClient]  # signed in through the sign-in page (cookies)
    bearer: dict[str, dict[str, str]]  # API headers
    private: int  # alice's private-track submission (failed episode with DETAIL)
    public: int  # alice's public-track submission (a replayable episode with DETAIL)
    public_episode: int
    episode: int
    participants: dict[str, int]


def _csrf(html: str) -> str:
    found = re.search(r'name="csrf" value="([^"]+)"', html)
    assert found is not None
    return found.group(1)


def sign_in(client: TestClient, token: str) -> None:
    page = client.get("/sign-in")
    r = client.post("/sign-in", data={"token": token, "csrf": _csrf(page.text)}, follow_redirects=False)
    assert r.status_code == 303, r.text


def _trace() -> dict[str, Any]:
    boxes = tuple(Box(30.0, 20.0, 10.0 + i, 2.0) for i in range(4))
    spec = EpisodeSpec("diverse", "train", 0, boxes, ContainerSpec(120, 100, 100), 7.0, 0)
    return run_episode(spec, load_policy("dbl"), "math").to_dict()


def _seed(client: TestClient, tokens: dict[str, str]) -> tuple[int, int, int, int]:
    with client.app.state.runtime.session() as s:  # type: ignore[attr-defined]
        alice = s.execute(select(Participant).where(Participant.name == "alice")).scalar_one()
        ids = []
        for track in ("private", "public"):
            sub = work.create_submission(
                s,
                alice,
                name=f"alice-{track}",
                policy_url=POLICY_URL,
                datasets=["diverse"],
                settings=["math"],
                groups=2,
                track=track,
            )
            s.flush()
            ep = s.execute(select(EpisodeRow).where(EpisodeRow.submission_id == sub.id)).scalars().first()
            ep.status, ep.termination, ep.termination_detail = "done", "policy_error", DETAIL
            ep.finished_at, ep.boxes_total, ep.boxes_placed = utcnow(), 4, 0
            if track == "public":
                ep.trace = _trace()
            sub.error = DETAIL
            if track == "private":  # finished and failed: a failed entry, shown apart on the public board
                for other in s.execute(
                    select(EpisodeRow).where(EpisodeRow.submission_id == sub.id)
                ).scalars():
                    other.status, other.termination, other.termination_detail = "done", "policy_error", DETAIL
                    other.finished_at, other.boxes_total, other.boxes_placed = utcnow(), 4, 0
                for run in sub.runs:
                    run.status, run.completed_at = "completed", utcnow()
                    run.metrics = {"space_utilization": 0.0, "occupancy": 0.0, "decision_time": 0.01}
                    run.extras = {
                        "terminations": {"policy_error": run.episodes_total},
                        "provenance": recorded_rules(),  # as finalize_run records it: current rules
                    }
                sub.status, sub.finished_at = "failed", utcnow()
            s.flush()
            ids += [sub.id, ep.id]
    return ids[0], ids[1], ids[2], ids[3]


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> Iterator[World]:
    tmp = tmp_path_factory.mktemp("visibility")
    app = create_app(make_settings(f"sqlite:///{tmp / 'v.sqlite3'}", tmp, quota_concurrent=9))
    with TestClient(app) as admin:
        bearer = {"operator": {"Authorization": f"Bearer {ADMIN_TOKEN}"}, "anonymous": {}}
        tokens, participants = {}, {}
        for who, name in (("owner", "alice"), ("other", "bob")):
            r = admin.post("/api/v1/participants", json={"name": name}, headers=bearer["operator"])
            assert r.status_code == 201, r.text
            tokens[who] = r.json()["token"]
            participants[who] = r.json()["participant"]["id"]
            bearer[who] = {"Authorization": f"Bearer {tokens[who]}"}
        private, episode, public, public_episode = _seed(admin, tokens)
        clients = {who: TestClient(app) for who in VIEWERS}
        for who, token in (("owner", tokens["owner"]), ("other", tokens["other"]), ("operator", ADMIN_TOKEN)):
            sign_in(clients[who], token)
        yield World(clients, bearer, private, public, public_episode, episode, participants)
        for c in clients.values():
            c.close()


def _status(w: World, sid: int) -> str:
    with w.clients["operator"].app.state.runtime.session() as s:  # type: ignore[attr-defined]
        return s.get(Submission, sid).status


# ---- pages ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("who", VIEWERS)
def test_submission_page_is_the_owners_and_the_operators(world: World, who: str) -> None:
    r = world.clients[who].get(f"/submissions/{world.private}")
    if who in ("owner", "operator"):
        assert r.status_code == 200
        html = r.text
        assert "&lt;script&gt;alert(" in html and "<script>alert(" not in html  # escaped
        assert LEAK in html and TAIL not in html and "\u202e" not in html  # shown, cut, cleaned
        assert POLICY_URL in html and 'id="episodes"' in html
        assert r.headers["cache-control"] == "private, no-store"
    else:
        assert r.status_code == 404
        # Exactly the answer a missing id gets: an id reveals nothing.
        missing = world.clients[who].get("/submissions/999999")
        assert r.text.replace(f"submission {world.private}.", "") == missing.text.replace(
            "submission 999999.", ""
        )
        assert LEAK not in r.text and "alice-private" not in r.text


@pytest.mark.parametrize("who", VIEWERS)
def test_status_json_is_the_owners_and_the_operators(world: World, who: str) -> None:
    r = world.clients[who].get(f"/submissions/{world.private}/status.json")
    if who in ("owner", "operator"):
        assert r.status_code == 200 and r.json()["id"] == world.private
    else:
        assert r.status_code == 404 and "progress" not in r.text


@pytest.mark.parametrize("who", VIEWERS)
def test_public_replay_shows_the_failure_reason_to_the_owner_only(world: World, who: str) -> None:
    """Replays of public-track episodes are public (like the board); the policy's own words are not."""
    r = world.clients[who].get(f"/submissions/{world.public}/episodes/{world.public_episode}/replay")
    assert r.status_code == 200
    assert "policy_error" in r.text  # how it ended is public
    assert TAIL not in r.text and "<script>alert(" not in r.text
    assert (LEAK in r.text) == (who in ("owner", "operator"))
    assert (f'href="/submissions/{world.public}"' in r.text) == (who in ("owner", "operator"))


@pytest.mark.parametrize("who", VIEWERS)
def test_boards_link_only_the_submission_pages_the_viewer_may_open(world: World, who: str) -> None:
    """Someone else's submission page is a 404, so the boards name it without a link."""
    for path in ("/boards/diverse/math", "/"):
        r = world.clients[who].get(path)
        assert "alice-private" in r.text, path
        assert (f'href="/submissions/{world.private}"' in r.text) == (who in ("owner", "operator")), path


@pytest.mark.parametrize("who", VIEWERS)
def test_account_lists_only_your_own_submissions(world: World, who: str) -> None:
    r = world.clients[who].get("/account", follow_redirects=False)
    if who == "anonymous":
        assert r.status_code == 303 and r.headers["location"] == "/sign-in"
        return
    assert r.status_code == 200
    assert ("alice-private" in r.text) == (who in ("owner", "operator"))
    assert LEAK not in r.text  # failure reasons are on the submission page, not in lists


@pytest.mark.parametrize("who", VIEWERS)
@pytest.mark.parametrize("path", ["/operator", "/operator/participants/{alice}"])
def test_operator_pages_are_the_operators(world: World, who: str, path: str) -> None:
    r = world.clients[who].get(path.format(alice=world.participants["owner"]))
    assert r.status_code == (200 if who == "operator" else 404)
    assert ('id="participants"' in r.text or 'id="issue-token"' in r.text) == (who == "operator")


@pytest.mark.parametrize("who", VIEWERS)
def test_public_pages_never_show_failure_reasons(world: World, who: str) -> None:
    board = world.clients[who].get("/boards/diverse/math")
    assert "alice-private" in board.text  # the failed entry is on the public board, by name...
    for path in ("/", "/?track=public", "/boards/diverse/math", "/boards/diverse/math?track=public"):
        r = world.clients[who].get(path)
        assert r.status_code == 200, path
        assert LEAK not in r.text and TAIL not in r.text and POLICY_URL not in r.text, (
            path
        )  # ...not its reasons
    api = world.clients["anonymous"].get("/api/v1/leaderboards/diverse/math")
    assert (
        api.status_code == 200
        and "alice-private" in api.text
        and LEAK not in api.text
        and TAIL not in api.text
    )


def test_cancel_form_needs_the_owner_and_a_csrf_token(world: World) -> None:
    with world.clients["operator"].app.state.runtime.session() as s:  # type: ignore[attr-defined]
        alice = s.execute(select(Participant).where(Participant.name == "alice")).scalar_one()
        sid = work.create_submission(
            s,
            alice,
            name="alice-cancel",
            policy_url=POLICY_URL,
            datasets=["diverse"],
            settings=["math"],
            groups=1,
        ).id
    other, owner, anon = world.clients["other"], world.clients["owner"], world.clients["anonymous"]
    r = other.post(f"/submissions/{sid}/cancel", data={"csrf": _csrf(other.get("/account").text)})
    assert r.status_code == 404 and _status(world, sid) == "queued"
    r = anon.post(f"/submissions/{sid}/cancel", data={"csrf": "x"})
    assert r.status_code == 404 and _status(world, sid) == "queued"
    r = owner.post(f"/submissions/{sid}/cancel", data={"csrf": "forged"})
    assert r.status_code == 403 and _status(world, sid) == "queued"
    page = owner.get(f"/submissions/{sid}")
    assert 'id="cancel-form"' in page.text
    r = owner.post(f"/submissions/{sid}/cancel", data={"csrf": _csrf(page.text)}, follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == f"/submissions/{sid}"
    assert _status(world, sid) == "cancelled"


# ---- the JSON API --------------------------------------------------------------------------------------


API_STATUS = {"anonymous": 401, "owner": 200, "other": 404, "operator": 200}


@pytest.mark.parametrize("who", VIEWERS)
@pytest.mark.parametrize(
    "route", ["/submissions/{sid}", "/submissions/{sid}/episodes", "/submissions/{sid}/episodes/{eid}"]
)
def test_api_routes_answer_the_owner_and_the_operator_only(world: World, who: str, route: str) -> None:
    path = "/api/v1" + route.format(sid=world.private, eid=world.episode)
    r = world.clients["anonymous"].get(path, headers=world.bearer[who])
    assert r.status_code == API_STATUS[who], r.text
    if r.status_code != 200:
        assert LEAK not in r.text
        return
    body = r.json()
    details = (
        [e["termination_detail"] for e in body]
        if isinstance(body, list)
        else [body.get("termination_detail")]
    )
    if "error" in body if isinstance(body, dict) else False:
        details.append(body["error"])
    details = [d for d in details if d]
    assert details, "the route shows no failure reason to its owner"
    for d in details:
        assert (
            len(d) <= SHOWN_TEXT_LIMIT and TAIL not in d and "\u202e" not in d and d.startswith("POST /act")
        )


@pytest.mark.parametrize("who", VIEWERS)
def test_api_list_and_cancel_keep_to_the_owner(world: World, who: str) -> None:
    r = world.clients["anonymous"].get("/api/v1/submissions", headers=world.bearer[who])
    if who == "anonymous":
        assert r.status_code == 401
    else:
        assert r.status_code == 200
        assert (world.private in {s["id"] for s in r.json()}) == (who in ("owner", "operator"))
    if who in ("anonymous", "other"):
        r = world.clients["anonymous"].post(
            f"/api/v1/submissions/{world.private}/cancel", headers=world.bearer[who]
        )
        assert r.status_code == API_STATUS[who]


# ---- the session itself --------------------------------------------------------------------------------


def test_session_cookie_is_signed_httponly_and_holds_no_token(world: World) -> None:
    app = world.clients["owner"].app
    with TestClient(app, base_url="https://testserver") as browser:
        page = browser.get("/sign-in")
        r = browser.post(
            "/sign-in", data={"token": ADMIN_TOKEN, "csrf": _csrf(page.text)}, follow_redirects=False
        )
        cookie = r.headers["set-cookie"]
        assert "HttpOnly" in cookie and "SameSite=lax" in cookie and "Secure" in cookie
        payload = cookie.split("=", 1)[1].split(".", 1)[0]
        assert ADMIN_TOKEN not in base64.urlsafe_b64decode(payload + "==").decode()
        # A tampered cookie is no session at all.
        value = cookie.split("=", 1)[1].split(";", 1)[0]
        # in place of the real one (httpx2 keeps a cookie set without a domain beside the server's)
        browser.cookies.clear()
        browser.cookies.set("robobpp_session", value[:-2] + ("AA" if not value.endswith("AA") else "BB"))
        assert browser.get("/operator").status_code == 404
    plain = world.clients["anonymous"].get("/sign-in").headers["set-cookie"]
    assert "Secure" not in plain and "HttpOnly" in plain


def test_sign_in_refuses_a_missing_csrf_token_and_bad_tokens(world: World) -> None:
    with TestClient(world.clients["owner"].app) as browser:
        r = browser.post("/sign-in", data={"token": ADMIN_TOKEN}, follow_redirects=False)
        assert r.status_code == 403 and browser.get("/operator").status_code == 404
        page = browser.get("/sign-in")
        r = browser.post(
            "/sign-in", data={"token": "rbp_nope", "csrf": _csrf(page.text)}, follow_redirects=False
        )
        assert r.status_code == 401 and "not valid" in r.text
        r = browser.post(
            "/sign-in",
            data={"token": ADMIN_TOKEN, "csrf": _csrf(page.text)},
            follow_redirects=False,
            headers={"Origin": "https://evil.example"},
        )
        assert r.status_code == 403 and browser.get("/operator").status_code == 404


def test_revoking_the_token_ends_its_browser_session(world: World) -> None:
    admin = world.bearer["operator"]
    with TestClient(world.clients["owner"].app) as browser:
        r = browser.post(f"/api/v1/participants/{world.participants['other']}/tokens", headers=admin)
        token, token_id = r.json()["token"], r.json()["id"]
        sign_in(browser, token)
        assert browser.get("/account").status_code == 200
        assert browser.delete(f"/api/v1/tokens/{token_id}", headers=admin).status_code == 200
        r = browser.get("/account", follow_redirects=False)
        assert r.status_code == 303 and r.headers["location"] == "/sign-in"
        assert browser.get("/submit", follow_redirects=False).status_code == 303


@pytest.mark.skipif(not PULL_OFFERED, reason="the API's submission model has no pull mode yet")
def test_submit_form_creates_a_pull_submission(world: World) -> None:
    app = world.clients["owner"].app
    r = world.clients["anonymous"].post(
        "/api/v1/participants", json={"name": "puller"}, headers=world.bearer["operator"]
    )
    with TestClient(app) as browser:
        sign_in(browser, r.json()["token"])
        form = browser.get("/submit")
        assert 'name="mode" value="pull"' in form.text
        r = browser.post(
            "/submit",
            data={
                "name": "pulled",
                "mode": "pull",
                "policy_url": "",
                "datasets": ["diverse"],
                "settings": ["math"],
                "csrf": _csrf(form.text),
            },
            follow_redirects=False,
        )
        assert r.status_code == 303, r.text
        page = browser.get(r.headers["location"])
        assert (
            "robobpp connect" in page.text
            and f"--submission {r.headers['location'].rsplit('/', 1)[1]}" in page.text
        )


def test_every_form_post_needs_the_csrf_token(world: World) -> None:
    """Each POST route of the pages, as the signed-in operator (who may do everything) without the form's
    token: refused with 403, nothing changed. A new form route without the check fails here."""
    operator = world.clients["operator"]
    app = operator.app
    with app.state.runtime.session() as s:  # type: ignore[attr-defined]
        alice = s.execute(select(Participant).where(Participant.name == "alice")).scalar_one()
        sid = work.create_submission(
            s,
            alice,
            name="alice-csrf",
            policy_url=POLICY_URL,
            datasets=["diverse"],
            settings=["math"],
            groups=1,
        ).id
        token_id = alice.tokens[0].id
    ids = {"submission_id": sid, "participant_id": world.participants["owner"], "token_id": token_id}

    def routes(router: Any) -> Iterator[Any]:  # FastAPI may keep an included router as one lazy entry
        for r in router.routes:
            inner = getattr(r, "original_router", None)
            yield from routes(inner) if inner is not None else [r]

    posts = [r.path for r in routes(pages.router) if "POST" in getattr(r, "methods", ())]
    assert len(posts) >= 7, posts
    before = operator.get(f"/operator/participants/{ids['participant_id']}").text.count("Revoke")
    for path in posts:
        r = operator.post(
            path.format(**ids), data={"csrf": "not-the-token", "name": "csrf-victim"}, follow_redirects=False
        )
        assert r.status_code == 403, (path, r.status_code)
    assert _status(world, sid) == "queued"
    assert operator.get("/account").status_code == 200  # still signed in
    page = operator.get(f"/operator/participants/{ids['participant_id']}").text
    assert page.count("Revoke") == before and "csrf-victim" not in operator.get("/operator").text


def test_submit_form_goes_through_the_api_handler(world: World, policy_server) -> None:
    """The form answers with the API's own checks (secret length, URL probe) and writes what the API writes."""
    policy = policy_server(secret="form-secret-123")
    admin = world.bearer["operator"]
    r = world.clients["anonymous"].post("/api/v1/participants", json={"name": "former"}, headers=admin)
    bearer = {"Authorization": f"Bearer {r.json()['token']}"}
    with TestClient(world.clients["owner"].app) as browser:
        sign_in(browser, r.json()["token"])
        form = browser.get("/submit")
        base = {
            "name": "formed",
            "policy_url": policy.url,
            "datasets": ["diverse"],
            "settings": ["math"],
            "csrf": _csrf(form.text),
        }
        short = browser.post("/submit", data={**base, "secret": "s3cret"})
        assert short.status_code == 422 and "secret" in short.text and "at least 8" in short.text
        wrong = browser.post("/submit", data={**base, "secret": "not-the-secret"})
        assert wrong.status_code == 422 and "Signature mismatch" in wrong.text
        assert browser.get("/api/v1/submissions", headers=bearer).json() == []  # nothing written
        ok = browser.post("/submit", data={**base, "secret": "form-secret-123"}, follow_redirects=False)
        assert ok.status_code == 303, ok.text
        listed = browser.get("/api/v1/submissions", headers=bearer).json()
        assert [f"/submissions/{s['id']}" for s in listed] == [ok.headers["location"]]
        assert listed[0]["participant"] == "former" and listed[0]["datasets"] == ["diverse"]
