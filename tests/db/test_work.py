"""The SQL work queue: leases, bounded retries, idempotent completion, cancel, concurrent claimers."""

from __future__ import annotations

import threading
from datetime import timedelta
from typing import Any

import pytest
from sqlalchemy import select

from robobpp.db import work
from robobpp.db.migrate import upgrade
from robobpp.db.models import EpisodeRow, Participant, RunRow, Submission, utcnow
from robobpp.db.session import make_engine, make_session_factory, transaction


@pytest.fixture
def factory(db_url: str):
    engine = make_engine(db_url)
    upgrade(db_url, engine=engine)
    yield make_session_factory(engine)
    engine.dispose()


def _submission(factory, groups: int = 2, datasets=("diverse",)) -> int:
    with transaction(factory) as s:
        p = s.execute(select(Participant).where(Participant.name == "p")).scalar_one_or_none()
        if p is None:
            p = Participant(name="p")
            s.add(p)
            s.flush()
        return work.create_submission(
            s,
            p,
            name="x",
            policy_url="builtin:dbl",
            datasets=list(datasets),
            settings=["math"],
            groups=groups,
        ).id


def _claim(factory, worker="w", now=None, max_attempts=3):
    with transaction(factory) as s:
        return work.claim_episode(s, worker, lease_s=10, max_attempts=max_attempts, now=now)


RESULT: dict[str, Any] = {
    "termination": "completed",
    "termination_detail": "",
    "boxes_total": 3,
    "boxes_placed": 3,
    "metrics": {"space_utilization": 0.5, "occupancy": 0.9, "decision_time": 0.01},
    "counters": {"placements_attempted": 3},
    "steps": [],
}


def _complete(factory, claim) -> bool:
    with transaction(factory) as s:
        return work.complete_episode(s, claim.episode_id, claim.token, RESULT, keep_trace=False)


def test_expired_lease_is_taken_over_and_the_old_claim_cannot_complete(factory) -> None:
    _submission(factory, groups=1)
    first = _claim(factory, "a")
    assert first is not None and _claim(factory, "b") is None  # leased
    later = utcnow() + timedelta(seconds=11)
    second = _claim(factory, "b", now=later)
    assert second is not None and second.episode_id == first.episode_id and second.attempt == 2
    assert not _complete(factory, first)  # stale claim: nothing written
    assert _complete(factory, second)
    assert not _complete(factory, second)  # idempotent: a repeat changes nothing
    with transaction(factory) as s:
        ep = s.get(EpisodeRow, second.episode_id)
        assert ep is not None
        run = s.get(RunRow, ep.run_id)
        sub = s.get(Submission, ep.submission_id)
        assert run is not None and run.metrics is not None and run.extras is not None and sub is not None
        assert (ep.status, ep.attempts, ep.worker) == ("done", 2, "b")
        assert run.status == "completed" and run.metrics["space_utilization"] == 0.5
        assert run.extras["episodes"] == 1 and sub.status == "completed"


def test_attempts_are_bounded_then_the_episode_is_recorded_failed(factory) -> None:
    sid = _submission(factory, groups=1)
    now = utcnow()
    for attempt in range(2):
        claim = _claim(factory, f"w{attempt}", now=now + timedelta(seconds=11 * attempt), max_attempts=2)
        assert claim is not None and claim.attempt == attempt + 1
    assert _claim(factory, "w9", now=now + timedelta(seconds=40), max_attempts=2) is None
    with transaction(factory) as s:
        ep = s.execute(select(EpisodeRow).where(EpisodeRow.submission_id == sid)).scalar_one()
        assert (ep.status, ep.termination) == ("failed", work.WORKER_LOST)
        submission = s.get(Submission, sid)
        assert submission is not None and submission.status == "failed"


def test_release_retries_infrastructure_errors_then_fails(factory) -> None:
    _submission(factory, groups=1)
    claim = _claim(factory, max_attempts=2)
    with transaction(factory) as s:
        assert work.release_episode(s, claim.episode_id, claim.token, "boom", max_attempts=2)
    again = _claim(factory, max_attempts=2)
    assert again.attempt == 2
    with transaction(factory) as s:
        assert work.release_episode(s, again.episode_id, again.token, "boom", max_attempts=2)
        episode = s.get(EpisodeRow, again.episode_id)
        assert episode is not None and episode.status == "failed"


def test_cancel_stops_claims_and_voids_running_claims(factory) -> None:
    sid = _submission(factory, groups=3)
    running = _claim(factory)
    with transaction(factory) as s:
        submission = s.get(Submission, sid)
        assert submission is not None
        assert work.cancel_submission(s, submission)
    assert _claim(factory) is None
    with transaction(factory) as s:
        assert not work.heartbeat(s, running.episode_id, running.token, lease_s=10, step=1)
    assert not _complete(factory, running)
    with transaction(factory) as s:
        statuses = s.execute(select(EpisodeRow.status).where(EpisodeRow.submission_id == sid)).scalars().all()
        assert statuses == ["cancelled"] * 3
        submission = s.get(Submission, sid)
        assert submission is not None
        assert not work.cancel_submission(s, submission)


def test_concurrent_claimers_never_share_an_episode(factory) -> None:
    _submission(factory, groups=10, datasets=("diverse", "longboard"))
    claimed: list[int] = []
    lock = threading.Lock()
    errors: list[BaseException] = []

    def worker(name: str) -> None:
        try:
            while (c := _claim(factory, name)) is not None:
                with lock:
                    claimed.append(c.episode_id)
                assert _complete(factory, c)
        except BaseException as exc:  # noqa: BLE001
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(f"t{i}",)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not errors
    assert sorted(claimed) == sorted(set(claimed)) and len(claimed) == 20
    with transaction(factory) as s:
        runs = s.execute(select(RunRow)).scalars().all()
        assert all(
            r.status == "completed" and r.extras is not None and r.extras["episodes"] == 10 for r in runs
        )


# ---- outbound bounds: a participant's remote policy gets at most N episodes at once; sends are marked once


def _remote(factory, name: str, url: str, groups: int = 4) -> int:
    with transaction(factory) as s:
        p = Participant(name=name)
        s.add(p)
        s.flush()
        return work.create_submission(
            s, p, name=name, policy_url=url, datasets=["diverse"], settings=["math"], groups=groups
        ).id


def _claim_limited(factory, limit: int):
    with transaction(factory) as s:
        return work.claim_episode(s, "w", lease_s=30, max_attempts=3, max_running_per_participant=limit)


def test_a_participant_gets_at_most_its_share_of_running_episodes(factory) -> None:
    greedy = _remote(factory, "greedy", "http://203.0.113.7:9000", groups=5)
    other = _remote(factory, "other", "http://203.0.113.8:9000", groups=1)
    baseline = _remote(factory, "builtin-ish", "builtin:dbl", groups=3)
    claims = [c for c in (_claim_limited(factory, 2) for _ in range(8)) if c is not None]
    by_sub = {s: sum(c.submission_id == s for c in claims) for s in (greedy, other, baseline)}
    # greedy's five episodes come first in id order, yet only two run; the others are not held back, and
    # built-in policies (no outbound call) are not limited.
    assert by_sub == {greedy: 2, other: 1, baseline: 3}
    assert _claim_limited(factory, 2) is None
    with transaction(factory) as s:  # one of greedy's finishes: the next one may start
        done = next(c for c in claims if c.submission_id == greedy)
        assert work.complete_episode(
            s,
            done.episode_id,
            done.token,
            {"termination": "completed", "boxes_total": 1, "boxes_placed": 1, "metrics": {}, "counters": {}},
            keep_trace=False,
        )
    nxt = _claim_limited(factory, 2)
    assert nxt is not None and nxt.submission_id == greedy


def _builtin(factory, name: str, groups: int) -> int:
    with transaction(factory) as s:
        p = Participant(name=name, is_builtin=True)
        s.add(p)
        s.flush()
        return work.create_submission(
            s, p, name=name, policy_url="builtin:dbl", datasets=["diverse"], settings=["math"], groups=groups
        ).id


def test_claims_are_fair_across_participants_and_baselines_come_last(factory) -> None:
    """Least running first, then oldest; the baselines (built-in participant) after every participant's work,
    although they were submitted first. First come, first served would give ``greedy`` its five episodes
    before ``late`` got one."""
    baseline = _builtin(factory, "baselines", groups=2)
    greedy = _remote(factory, "greedy", "http://203.0.113.7:9000", groups=5)
    late = _remote(factory, "late", "http://203.0.113.8:9000", groups=2)
    order = [c.submission_id for c in (_claim(factory) for _ in range(9)) if c is not None]
    assert order == [greedy, late, greedy, late, greedy, greedy, greedy, baseline, baseline]


def test_a_participant_whose_episodes_all_finished_does_not_take_every_freed_slot_back(factory) -> None:
    """Both of greedy's running episodes finish at once (so it has none running, like the newcomer): the freed
    slots go round-robin by last start, not both to greedy's older episodes."""
    greedy = _remote(factory, "greedy", "http://203.0.113.7:9000", groups=4)
    first = [_claim(factory), _claim(factory)]
    late = _remote(factory, "late", "http://203.0.113.8:9000", groups=1)
    for claim in first:
        assert _complete(factory, claim)
    assert [_claim(factory).submission_id for _ in range(2)] == [late, greedy]


def test_a_message_claims_the_fairest_episode_that_has_one_out(factory) -> None:
    """Celery: the broker hands messages out in the order they were sent, but a message is a ticket for the
    fairest episode with a message out; an episode with no message out is not taken, and a message claims
    its own episode when no other is free."""
    greedy = _remote(factory, "greedy", "http://203.0.113.7:9000", groups=3)
    late = _remote(factory, "late", "http://203.0.113.8:9000", groups=1)
    unsent = _remote(factory, "unsent", "http://203.0.113.9:9000", groups=1)
    with transaction(factory) as s:
        ids = {
            sub: [
                e.id
                for e in s.execute(
                    select(EpisodeRow).where(EpisodeRow.submission_id == sub).order_by(EpisodeRow.id)
                ).scalars()
            ]
            for sub in (greedy, late, unsent)
        }
        work.take_unsent(s, stale_after_s=3600, ids=ids[greedy] + ids[late])

    def by_message(episode_id: int):
        with transaction(factory) as s:
            return work.claim_episode(s, "w", lease_s=30, max_attempts=3, episode_id=episode_id)

    first = by_message(ids[greedy][0])  # greedy's messages were sent first
    second = by_message(ids[greedy][1])
    assert (first.episode_id, second.episode_id) == (ids[greedy][0], ids[late][0])
    third = by_message(ids[greedy][2])
    assert third.episode_id == ids[greedy][1]
    last = by_message(ids[unsent][0])  # no other episode with a message out is free: its own
    assert last.episode_id == ids[greedy][2]
    assert by_message(ids[unsent][0]).episode_id == ids[unsent][0]


def test_pending_episodes_are_sent_once_and_lost_messages_again(factory) -> None:
    sub = _remote(factory, "p", "builtin:dbl", groups=3)
    with transaction(factory) as s:
        first = work.take_unsent(s, stale_after_s=3600)
    with transaction(factory) as s:
        again = work.take_unsent(s, stale_after_s=3600)  # what a restarted dispatcher would send
    with transaction(factory) as s:
        stale = work.take_unsent(s, stale_after_s=3600, now=utcnow() + timedelta(hours=2))
        ids = set(s.execute(select(EpisodeRow.id).where(EpisodeRow.submission_id == sub)).scalars())
    assert set(first) == ids and again == [] and set(stale) == ids


def test_a_runs_figures_do_not_depend_on_the_order_its_episodes_finished(factory) -> None:
    """Two runs of the same per-group figures give the same metrics to the last bit, whichever episode finished
    first: a float mean depends on its order, and the relative score's min-max would tell them apart."""
    utilisation = [0.1, 0.2, 0.3, 0.15, 0.25, 0.35, 0.05, 0.4]  # sums whose last bit depends on the order
    first, second = _submission(factory, groups=8), _submission(factory, groups=8)
    claims = [_claim(factory) for _ in range(16)]
    by_submission = {
        sid: sorted((c for c in claims if c.submission_id == sid), key=lambda c: c.group)
        for sid in (first, second)
    }
    for order in (by_submission[first], by_submission[second][::-1]):
        for claim in order:
            result = {
                **RESULT,
                "metrics": {**RESULT["metrics"], "space_utilization": utilisation[claim.group]},
            }
            with transaction(factory) as s:
                assert work.complete_episode(s, claim.episode_id, claim.token, result, keep_trace=False)
    with factory() as s:
        runs = {r.submission_id: r.metrics for r in s.execute(select(RunRow)).scalars()}
    assert runs[first] == runs[second]
