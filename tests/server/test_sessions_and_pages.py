"""Sessions and pages against an attacker (issue: signing out did not end a session, wrong tokens were unlimited,
the replay's 404 told private episodes from missing ones, pages had no CSP or framing policy, /metrics was
public, a baseline's private episode showed its simulator text to everyone, and a policy learnt the split and
group of each episode from its id). One in-process app on SQLite, a real worker unit for the ids."""

from __future__ import annotations

import base64
import hashlib
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select, update

from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.db import work
from robobpp.db.models import EpisodeRow, Participant, Submission, utcnow
from robobpp.policies.dbl import DBL
from robobpp.server import pages
from robobpp.server.app import create_app
from robobpp.server.site.render import CSRF_SLOT, render
from robobpp.worker.options import WorkerOptions
from robobpp.worker.run import claim_and_run
from tests.server.conftest import ADMIN_TOKEN, OFFLINE
from tests.server.test_api import ADMIN, make_settings

DETAIL = "box top at 41.5 cm"


@pytest.fixture
def app(tmp_path: Path) -> Iterator[Any]:
    application = create_app(
        make_settings(f"sqlite:///{tmp_path / 'pages.sqlite3'}", tmp_path, auth_failures_per_minute=5)
    )
    with TestClient(application):
        yield application
    application.state.runtime.dispose()


def _csrf(html: str) -> str:
    found = re.search(r'name="csrf" value="([^"]+)"', html)
    assert found is not None
    return found.group(1)


def _sign_in(client: TestClient, token: str) -> Any:
    return client.post(
        "/sign-in", data={"token": token, "csrf": _csrf(client.get("/sign-in").text)}, follow_redirects=False
    )


def _participant(client: TestClient, name: str) -> str:
    r = client.post("/api/v1/participants", json={"name": name}, headers=ADMIN)
    assert r.status_code == 201, r.text
    return str(r.json()["token"])


def _submission(
    app: Any, name: str, *, track: str, builtin: bool = False, policy: str = "builtin:dbl"
) -> int:
    with app.state.runtime.session() as s:
        p = s.execute(select(Participant).where(Participant.name == name)).scalar_one_or_none()
        if p is None:
            p = Participant(name=name, is_builtin=builtin)
            s.add(p)
            s.flush()
        return work.create_submission(
            s, p, name=name, policy_url=policy, datasets=["diverse"], settings=["math"], groups=2, track=track
        ).id


def _episodes(app: Any, sid: int) -> list[int]:
    with app.state.runtime.session() as s:
        return list(
            s.execute(
                select(EpisodeRow.id).where(EpisodeRow.submission_id == sid).order_by(EpisodeRow.id)
            ).scalars()
        )


def test_sign_out_ends_the_session_for_every_copy_of_the_cookie(app: Any) -> None:
    with TestClient(app) as admin_client:
        token = _participant(admin_client, "alice")
    with TestClient(app) as browser, TestClient(app) as thief:
        assert _sign_in(browser, token).status_code == 303
        cookie = browser.cookies.get("robobpp_session")
        assert cookie is not None
        thief.cookies.set("robobpp_session", cookie)
        assert thief.get("/account", follow_redirects=False).status_code == 200  # a copied cookie works...
        r = browser.post(
            "/sign-out", data={"csrf": _csrf(browser.get("/account").text)}, follow_redirects=False
        )
        assert r.status_code == 303
        gone = thief.get("/account", follow_redirects=False)  # ...until its owner signs out
        assert gone.status_code == 303 and gone.headers["location"].endswith("/sign-in")
        # The operator's session too.
        assert _sign_in(browser, ADMIN_TOKEN).status_code == 303
        cookie = browser.cookies.get("robobpp_session")
        assert cookie is not None
        thief.cookies.set("robobpp_session", cookie)
        assert thief.get("/operator", follow_redirects=False).status_code == 200
        browser.post("/sign-out", data={"csrf": _csrf(browser.get("/operator").text)})
        assert thief.get("/operator", follow_redirects=False).status_code != 200


def test_wrong_tokens_are_rate_limited_per_client(app: Any) -> None:
    with TestClient(app) as client:
        token = _participant(client, "bob")
        for _ in range(5):
            assert client.get("/api/v1/me", headers={"Authorization": "Bearer rbp_wrong"}).status_code == 401
        r = client.get("/api/v1/me", headers={"Authorization": "Bearer rbp_wrong"})
        assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1, r.text
        # Refused before any look-up, whatever the token: the address must wait.
        assert client.get("/api/v1/me", headers={"Authorization": f"Bearer {token}"}).status_code == 429
        assert _sign_in(client, token).status_code == 429
    with TestClient(app, client=("203.0.113.5", 5000)) as elsewhere:  # another address is not held back
        assert elsewhere.get("/api/v1/me", headers={"Authorization": f"Bearer {token}"}).status_code == 200
        for i in range(5):  # each its own prefix: a prefix is limited too (another test)
            assert _sign_in(elsewhere, f"rbp_w{i}rong").status_code == 401  # the sign-in form counts too
        assert _sign_in(elsewhere, token).status_code == 429


def test_one_404_for_a_missing_and_a_hidden_replay(app: Any) -> None:
    private = _submission(app, "carol", track="private")
    public = _submission(app, "carol", track="public")
    hidden, untraced = _episodes(app, private)[0], _episodes(app, public)[0]
    with TestClient(app) as client:
        answers = {}
        for sid, eid in ((private, hidden), (public, untraced), (private, 999_999), (999_998, 999_999)):
            r = client.get(f"/submissions/{sid}/episodes/{eid}/replay")
            named = f"episode {eid} in submission {sid}"
            assert named in r.text
            answers[(sid, eid)] = (r.status_code, r.text.replace(named, "episode E in submission S"))
    assert len(set(answers.values())) == 1, answers
    assert next(iter(answers.values()))[0] == 404


def test_pages_carry_a_content_security_policy_and_refuse_framing(app: Any) -> None:
    with TestClient(app) as client:
        for path in ("/", "/sign-in", "/docs"):
            r = client.get(path)
            assert r.status_code == 200
            csp = r.headers["content-security-policy"]
            assert "frame-ancestors 'none'" in csp and "default-src 'self'" in csp, csp
            script_src = next(p for p in csp.split(";") if p.strip().startswith("script-src"))
            assert "'unsafe-inline'" not in script_src
            assert r.headers["x-frame-options"] == "DENY"
            assert r.headers["referrer-policy"] == "same-origin"
            assert r.headers["x-content-type-options"] == "nosniff"
            for body in re.findall(rb"<script(?![^>]*src=)[^>]*>(.*?)</script>", r.content, re.S):
                digest = base64.b64encode(hashlib.sha256(body).digest()).decode()
                assert f"'sha256-{digest}'" in script_src  # the page's own inline scripts still run
        assert "content-security-policy" not in client.get("/api/v1/info").headers  # JSON: not a page


def test_metrics_need_the_admin_token_unless_opened(app: Any, tmp_path: Path) -> None:
    with TestClient(app) as client:
        assert client.get("/metrics").status_code == 401
        assert client.get("/metrics", headers={"Authorization": "Bearer rbp_wrong"}).status_code == 401
        assert "robobpp_episodes" in client.get("/metrics", headers=ADMIN).text
    opened = create_app(
        make_settings(f"sqlite:///{tmp_path / 'open.sqlite3'}", tmp_path / "open", metrics_public=True)
    )
    with TestClient(opened) as client:
        assert client.get("/metrics").status_code == 200


def test_a_baselines_private_episode_shows_no_termination_detail_to_participants(app: Any) -> None:
    baseline = _submission(app, "baselines", track="private", builtin=True)
    first = _episodes(app, baseline)[0]
    with app.state.runtime.session() as s:
        s.execute(
            update(EpisodeRow)
            .where(EpisodeRow.id == first)
            .values(status="failed", termination="collapse", termination_detail=DETAIL)
        )
    with TestClient(app) as client:
        dave = {"Authorization": f"Bearer {_participant(client, 'dave')}"}
        listed = client.get(f"/api/v1/submissions/{baseline}/episodes", headers=dave).json()
        one = client.get(f"/api/v1/submissions/{baseline}/episodes/{first}", headers=dave).json()
        assert listed[0]["termination"] == one["termination"] == "collapse"  # how it ended: public
        assert DETAIL not in str(listed) and DETAIL not in str(one)  # the simulator's words: not
        assert (
            client.get(f"/api/v1/submissions/{baseline}/episodes", headers=ADMIN).json()[0][
                "termination_detail"
            ]
            == DETAIL
        )
        page = client.get(f"/submissions/{baseline}")
        assert page.status_code == 200 and DETAIL not in page.text


class Recorder(DBL):
    """Remembers the episode ids it is told (in this process: the worker unit runs here)."""

    seen: ClassVar[list[str]] = []

    def reset(self, info: EpisodeInfo) -> None:
        Recorder.seen.append(info.episode_id)
        super().reset(info)

    def act(self, obs: Observation) -> Action | None:
        assert obs.episode_id == Recorder.seen[-1]
        return super().act(obs)


def test_the_ids_a_policy_sees_name_neither_split_nor_group(app: Any) -> None:
    """A participant's policy (here served over HTTP, as any remote one) is told an opaque id per episode; the
    built-in policies keep the readable one, which Random and PCT seed from (same figures on every run)."""
    from robobpp.client.serve import BackgroundServer, create_policy_app

    options = WorkerOptions(database_url=app.state.settings.sqlalchemy_url, groups=2, spec_provider=OFFLINE)
    factory = app.state.runtime.session_factory
    with BackgroundServer(create_policy_app(Recorder, None)) as remote:
        Recorder.seen.clear()
        sid = _submission(app, "erin", track="private", policy=remote.url)
        while claim_and_run(factory, options, "test:worker") is not None:
            pass
        remote_ids = list(Recorder.seen)
    Recorder.seen.clear()
    _submission(
        app,
        "baselines",
        track="private",
        builtin=True,
        policy="builtin:tests.server.test_sessions_and_pages:Recorder",
    )
    while claim_and_run(factory, options, "test:worker") is not None:
        pass
    assert sorted(Recorder.seen) == ["diverse-test-000", "diverse-test-001"]
    assert len(remote_ids) == 2 and len(set(remote_ids)) == 2
    for seen in remote_ids:
        assert re.fullmatch(r"ep-[0-9a-f]{16}", seen), seen  # was "diverse-test-000"
    with app.state.runtime.session() as s:
        assert set(s.execute(select(EpisodeRow.status).where(EpisodeRow.submission_id == sid)).scalars()) == {
            "done"
        }


def _finish(app: Any, sid: int) -> None:
    with app.state.runtime.session() as s:
        s.execute(
            update(Submission).where(Submission.id == sid).values(status="completed", finished_at=utcnow())
        )


def test_a_finished_submissions_page_is_rendered_once_and_carries_each_viewers_own_nonce(
    app: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Kept per kind of viewer and publication, the page still carries the nonce of the browser that asks:
    its forms (sign-out) work for that browser and for no other."""
    with TestClient(app) as admin_client:
        token = _participant(admin_client, "erin")
    sid = _submission(app, "erin", track="private")
    _finish(app, sid)
    rendered: list[str] = []
    original = render  # what pages.render names

    def counting(request: Any, template: str, *args: Any, **kwargs: Any) -> Any:
        rendered.append(template)
        return original(request, template, *args, **kwargs)

    monkeypatch.setattr(pages, "render", counting)
    with TestClient(app) as one, TestClient(app) as two:
        assert _sign_in(one, token).status_code == _sign_in(two, token).status_code == 303
        first, second = one.get(f"/submissions/{sid}"), two.get(f"/submissions/{sid}")
        assert first.status_code == second.status_code == 200
        assert rendered.count("submission.html") == 1  # the second viewer got the kept page
        assert CSRF_SLOT not in first.text and CSRF_SLOT not in second.text
        assert first.headers["cache-control"] == second.headers["cache-control"] == "private, no-store"
        mine, theirs = _csrf(first.text), _csrf(second.text)
        assert mine != theirs and mine == _csrf(one.get("/account").text)
        assert two.post("/sign-out", data={"csrf": mine}, follow_redirects=False).status_code == 403
        assert two.post("/sign-out", data={"csrf": theirs}, follow_redirects=False).status_code == 303
        assert two.get(f"/submissions/{sid}").status_code == 404  # signed out: not its page any more
        assert one.get(f"/submissions/{sid}").status_code == 200


@pytest.mark.parametrize(
    "path", ["/account", "/submissions/{sid}", "/submissions/{sid}/status.json", "/operator"]
)
def test_a_signed_in_page_reads_its_viewer_in_its_own_transaction(app: Any, path: str) -> None:
    """The session and token rows are read in the page's one transaction, not in one of their own before it
    (each costs a worker-thread hand-off and four round trips under load)."""
    with TestClient(app) as admin_client:
        token = _participant(admin_client, "frank")
    sid = _submission(app, "frank", track="private")
    runtime = app.state.runtime
    opened: list[int] = []
    original = runtime.read_session

    def counting() -> Any:
        opened.append(1)
        return original()

    with TestClient(app) as browser:
        assert _sign_in(browser, ADMIN_TOKEN if path == "/operator" else token).status_code == 303
        url = path.format(sid=sid)
        assert browser.get(url).status_code == 200  # warm: the kept forms
        runtime.read_session = counting
        try:
            assert browser.get(url).status_code == 200
        finally:
            del runtime.read_session
        assert len(opened) == 1


def test_a_kept_submission_row_carries_each_viewers_own_nonce(app: Any) -> None:
    """The account page's rows are kept as HTML for every viewer; the cancel form of an active submission
    must still carry the nonce of the browser that reads it."""
    with TestClient(app) as admin_client:
        token = _participant(admin_client, "gina")
    sid = _submission(app, "gina", track="private")  # queued: its row has a cancel form
    with TestClient(app) as one, TestClient(app) as two:
        assert _sign_in(one, token).status_code == _sign_in(two, token).status_code == 303
        first, second = one.get("/account").text, two.get("/account").text
        forms = [
            re.findall(rf'/submissions/{sid}/cancel".*?name="csrf" value="([^"]+)"', t)
            for t in (first, second)
        ]
        assert forms[0] == [_csrf(one.get("/account").text)] and forms[1] == [_csrf(second)]
        assert forms[0] != forms[1] and CSRF_SLOT not in first + second
        cancel = f"/submissions/{sid}/cancel"
        assert two.post(cancel, data={"csrf": forms[0][0]}, follow_redirects=False).status_code == 403
        assert two.post(cancel, data={"csrf": forms[1][0]}, follow_redirects=False).status_code == 303


def test_the_take_part_page_says_decision_time_as_the_readme_does(app: Any) -> None:
    """The page said Decision Time was "the round trip of /act"; the evaluator subtracts its network estimate."""
    with TestClient(app) as client:
        page = client.get("/protocol").text
    assert "the round trip of <code>/act</code> minus its estimate of the network round trip" in page
    assert "(the round trip of <code>/act</code>)" not in page
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    assert "minus its own estimate of the network round trip" in readme  # the wording the page follows
