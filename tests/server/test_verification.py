"""Verification on the hold-out draw (docs/server.md, threat model): an honest policy is verified; a policy
tuned to the played groups — here one that memorised their boxes and gives up on anything else — is
flagged ``disagrees``, on the submission and on the board."""

from __future__ import annotations

import threading
from typing import Any

import pytest

from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.db.verification import agree, interval
from robobpp.policies.dbl import DBL
from robobpp.worker.specs import offline_spec
from tests.server.conftest import ADMIN_TOKEN, db_rows, new_participant, wait_for

GROUPS = 4
DATASET = "diverse"


def test_interval_and_agreement() -> None:
    a = interval([0.50, 0.55, 0.60])
    assert a["low"] < a["mean"] < a["high"] and a["mean"] == pytest.approx(0.55)
    assert agree(a, interval([0.52, 0.58, 0.61]))
    assert not agree(a, interval([0.20, 0.22, 0.25]))
    assert interval([0.4])["low"] == interval([0.4])["high"] == 0.4


class Memoriser(DBL):
    """Plays DBL on box sequences it recorded from the played groups, and gives up on any other — once
    ``released`` is set: until then its verification stays running, so the test sees it running (giving up at
    once finished the whole hold-out run before the test asked, and a second verification was then allowed)."""

    def __init__(self, recorded: list[tuple[tuple[float, float, float], ...]]) -> None:
        super().__init__()
        self.recorded = recorded
        self.released = threading.Event()
        self.seen: dict[str, list[tuple[float, float, float]]] = {}  # per episode: two workers call at once

    def reset(self, info: EpisodeInfo) -> None:
        self.seen[info.episode_id] = []

    def act(self, obs: Observation) -> Action | None:
        seen = self.seen.setdefault(obs.episode_id, [])
        seen.append((obs.box.length, obs.box.width, obs.box.height))
        if not any(seq[: len(seen)] == tuple(seen) for seq in self.recorded):
            self.released.wait(60)
            return None  # an unknown group: no tuned answer for it
        return super().act(obs)


def _played_sequences() -> list[tuple[tuple[float, float, float], ...]]:
    """What a participant records by playing the private track once: the boxes of every played group."""
    return [
        tuple((b.length, b.width, b.height) for b in offline_spec(DATASET, "test", g, GROUPS).boxes)
        for g in range(GROUPS)
    ]


def test_tuned_policy_disagrees_and_honest_baseline_is_verified(make_server, policy_server, tmp_path) -> None:
    url = f"sqlite:///{tmp_path / 'verify.sqlite3'}"
    server = make_server(url, ROBOBPP_GROUPS=str(GROUPS), ROBOBPP_DATASETS=f'["{DATASET}"]')
    tuner = Memoriser(_played_sequences())
    memoriser = policy_server(tuner)
    with server.client(ADMIN_TOKEN) as admin:
        token = new_participant(admin, "tuner")
        with server.client(token) as alice:
            r = alice.post(
                "/submissions",
                json={"name": "tuned", "policy_url": memoriser.url, "secret": "policy-secret-123"},
            )
            assert r.status_code == 201, r.text
        tuned = r.json()["id"]
        (baseline,) = [
            s["id"]
            for s in admin.get("/submissions").json()
            if s["policy_url"] == "builtin:dbl" and s["track"] == "private"
        ]

        def status(i: int) -> str:
            return admin.get(f"/submissions/{i}").json()["status"]

        wait_for(lambda: status(tuned) == "completed" and status(baseline) == "completed", 120)
        # The operator verifies the board's top entries (here both: the tuned policy and the baseline).
        r = admin.post(f"/leaderboards/{DATASET}/math/verify", params={"top": 2})
        assert r.status_code == 201, r.text
        assert len(r.json()) == 2 and {v["track"] for v in r.json()} == {"verify"}
        running = {o: admin.get(f"/submissions/{o}").json()["verification"] for o in (tuned, baseline)}
        assert {v["status"] for v in running.values()} == {"running"}
        checks = {o: v["submission_id"] for o, v in running.items()}
        assert set(checks.values()) == {v["id"] for v in r.json()}
        assert admin.post(f"/leaderboards/{DATASET}/math/verify", params={"top": 2}).json() == []  # not twice
        assert admin.post(f"/submissions/{tuned}/verify").status_code == 409  # one at a time
        with server.client(token) as alice:
            assert alice.post(f"/submissions/{tuned}/verify").status_code == 403  # operator only
        tuner.released.set()
        wait_for(lambda: all(status(v) == "completed" for v in checks.values()), 120)

        verdicts: dict[int, Any] = {o: admin.get(f"/submissions/{o}").json()["verification"] for o in checks}
        board = admin.get(f"/leaderboards/{DATASET}/math").json()["entries"]

    assert verdicts[tuned]["status"] == "disagrees", verdicts[tuned]
    assert verdicts[baseline]["status"] == "verified", verdicts[baseline]
    (run,) = verdicts[tuned]["runs"]
    assert run["played"]["n"] == run["holdout"]["n"] == GROUPS
    assert run["played"]["method"] == run["holdout"]["method"] == "bootstrap"  # the board's own intervals
    assert run["holdout"]["high"] < run["played"]["low"]  # tuned: good where it was tuned, not elsewhere
    # The hold-out groups are other boxes under the same episode ids, and no verification is on a board.
    played = db_rows(url, "SELECT split, metrics FROM episodes WHERE submission_id = :s", s=tuned)
    holdout = db_rows(url, "SELECT split FROM episodes WHERE submission_id = :s", s=checks[tuned])
    assert {r.split for r in played} == {"test"} and {r.split for r in holdout} == {"holdout"}
    on_board = {e["submission_id"]: e["verification"] for e in board}
    assert set(checks.values()).isdisjoint(on_board)
    assert on_board[tuned] == "disagrees" and on_board[baseline] == "verified"


def test_verifying_a_pull_submission_is_a_pull_submission_its_client_serves(make_server, tmp_path) -> None:
    """The operator's re-check of a pull-mode entry used to be a *push* job to the URL ``pull:`` (every
    episode failed: "policy URL must be http(s)://…"); it is a pull submission the participant's client joins."""
    from robobpp.client.connect import connect

    server = make_server(
        f"sqlite:///{tmp_path / 'pull-verify.sqlite3'}",
        ROBOBPP_GROUPS="2",
        ROBOBPP_DATASETS=f'["{DATASET}"]',
        ROBOBPP_SETTINGS='["math"]',
    )
    with server.client(ADMIN_TOKEN) as admin:
        token = new_participant(admin, "natted")
        played = connect(DBL(), server.url, token, secret="pull-secret-123", name="behind-nat", poll_s=0.3)
        assert played.status == "completed"
        r = admin.post(f"/submissions/{played.id}/verify")
        assert r.status_code == 201, r.text
        check = r.json()
        assert (check["mode"], check["policy_url"], check["track"]) == ("pull", "pull:", "verify")
        # The participant's client joins the verification as any pull submission (robobpp connect --submission).
        done = connect(DBL(), server.url, token, submission=check["id"], secret="pull-secret-123", poll_s=0.3)
        assert done.status == "completed"
        verdict = admin.get(f"/submissions/{played.id}").json()["verification"]
        episodes = admin.get(f"/submissions/{check['id']}/episodes").json()
    assert verdict["status"] == "verified", verdict
    assert all(e["status"] == "done" and e["termination"] != "policy_error" for e in episodes), episodes


def test_only_the_operator_controls_a_verification(make_server, policy_server, tmp_path) -> None:
    """The re-run is the operator's: its participant cannot cancel it (before: 200, and the original's verdict
    became ``cancelled`` and vanished from the board), the board shows ``pending`` while it runs, and the
    operator can still cancel it."""
    url = f"sqlite:///{tmp_path / 'own.sqlite3'}"
    server = make_server(
        url,
        ROBOBPP_GROUPS="2",
        ROBOBPP_DATASETS=f'["{DATASET}"]',
        ROBOBPP_EVALUATE_BASELINES="0",
        ROBOBPP_WORKERS="1",
    )
    policy = policy_server(SlowDBLVerify)
    with server.client(ADMIN_TOKEN) as admin, server.client(new_participant(admin, "owner")) as owner:
        r = owner.post(
            "/submissions", json={"name": "mine", "policy_url": policy.url, "secret": "policy-secret-123"}
        )
        assert r.status_code == 201, r.text
        original = r.json()["id"]
        wait_for(lambda: owner.get(f"/submissions/{original}").json()["status"] == "completed", 180)
        r = admin.post(f"/submissions/{original}/verify")
        assert r.status_code == 201, r.text
        check = r.json()["id"]
        listed = {s["id"]: s for s in owner.get("/submissions").json()}
        r = owner.post(f"/submissions/{check}/cancel")
        assert r.status_code == 403 and "operator" in r.json()["detail"], r.text
        assert owner.get(f"/submissions/{original}").json()["verification"]["status"] == "running"
        (entry,) = admin.get(f"/leaderboards/{DATASET}/math").json()["entries"]
        assert entry["submission_id"] == original and entry["verification"] == "pending"
        import httpx

        page = httpx.get(f"{server.url}/boards/{DATASET}/math", timeout=30).text
        assert "hold-out: pending" in page
        if check in listed:  # the owner sees the re-run, but its page offers no cancel button
            html = _signed_in_page(
                server.url, owner.headers["Authorization"].split()[1], f"/submissions/{check}"
            )
            assert f"/submissions/{check}/cancel" not in html
        r = admin.post(f"/submissions/{check}/cancel")
        assert r.status_code == 200 and r.json()["status"] == "cancelled"
        (entry,) = admin.get(f"/leaderboards/{DATASET}/math").json()["entries"]
        assert entry["verification"] is None


class SlowDBLVerify(DBL):
    """Slow enough that the verification is still running while the test acts."""

    def act(self, obs: Observation) -> Action | None:
        import time

        time.sleep(0.3)
        return super().act(obs)


def _signed_in_page(base: str, token: str, path: str) -> str:
    import re

    import httpx

    with httpx.Client(base_url=base, timeout=30) as browser:
        csrf = re.search(r'name="csrf" value="([^"]+)"', browser.get("/sign-in").text)
        assert csrf is not None
        browser.post("/sign-in", data={"token": token, "csrf": csrf.group(1)})
        return browser.get(path).text


def test_a_policy_taken_offline_for_the_re_run_is_unverifiable_not_failed(
    make_server, policy_server, tmp_path
) -> None:
    """Before: the participant stopped its policy server while the hold-out re-run ran, every episode ended in
    ``policy_error``, and the verdict was ``failed`` (the service's failure, as far as anyone could tell), which
    the board's ``verify?top=N`` started again: a way out of ``disagrees``. Now it is ``unverifiable``, and it
    stands."""
    server = make_server(
        f"sqlite:///{tmp_path / 'offline.sqlite3'}",
        ROBOBPP_GROUPS="2",
        ROBOBPP_DATASETS=f'["{DATASET}"]',
        ROBOBPP_EVALUATE_BASELINES="0",
    )
    policy = policy_server(DBL)
    with server.client(ADMIN_TOKEN) as admin, server.client(new_participant(admin, "dodger")) as owner:
        r = owner.post(
            "/submissions", json={"name": "dodge", "policy_url": policy.url, "secret": "policy-secret-123"}
        )
        assert r.status_code == 201, r.text
        original = r.json()["id"]
        wait_for(lambda: owner.get(f"/submissions/{original}").json()["status"] == "completed", 180)
        policy.stop()  # offline for the re-run
        r = admin.post(f"/submissions/{original}/verify")
        assert r.status_code == 201, r.text
        check = r.json()["id"]
        wait_for(lambda: admin.get(f"/submissions/{check}").json()["status"] in ("completed", "failed"), 180)
        verdict = admin.get(f"/submissions/{original}").json()["verification"]
        (entry,) = admin.get(f"/leaderboards/{DATASET}/math").json()["entries"]
        again = admin.post(f"/leaderboards/{DATASET}/math/verify", params={"top": 1})
    assert verdict["status"] == "unverifiable", verdict
    assert verdict["runs"][0]["policy_failed"] is True and verdict["runs"][0]["agree"] is None
    assert entry["submission_id"] == original and entry["verification"] == "unverifiable"
    assert again.status_code == 201 and again.json() == []  # it stands: not started again


def test_a_pull_client_that_never_joins_the_re_run_is_unverifiable(make_server, tmp_path) -> None:
    """The pull-mode way out: no client joins the verification, its episodes fail for want of one."""
    from robobpp.client.connect import connect

    server = make_server(
        f"sqlite:///{tmp_path / 'absent.sqlite3'}",
        ROBOBPP_GROUPS="2",
        ROBOBPP_DATASETS=f'["{DATASET}"]',
        ROBOBPP_EVALUATE_BASELINES="0",
        ROBOBPP_PULL_WAIT_S="4",
        ROBOBPP_MAX_ATTEMPTS="2",
    )
    with server.client(ADMIN_TOKEN) as admin:
        token = new_participant(admin, "absent")
        played = connect(DBL(), server.url, token, secret="pull-secret-123", name="gone", poll_s=0.3)
        assert played.status == "completed"
        r = admin.post(f"/submissions/{played.id}/verify")
        assert r.status_code == 201, r.text
        check = r.json()["id"]
        wait_for(lambda: admin.get(f"/submissions/{check}").json()["status"] in ("completed", "failed"), 180)
        verdict = admin.get(f"/submissions/{played.id}").json()["verification"]
    assert verdict["status"] == "unverifiable", verdict
    assert verdict["unserved_episodes"] == 2
