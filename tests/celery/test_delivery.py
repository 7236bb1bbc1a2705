"""Messages that are marked sent but can no longer reach a worker are sent again (real brokers, real workers).

``episodes.enqueued_at`` records that a message was sent. Before the lost-message check, a pending episode
whose message had vanished — lost by the broker, or reserved by a worker killed before its claim, which
Redis hands out again only after its visibility timeout (an hour with the defaults) — stayed pending that
long. Each test below fails without the check (the episode never runs, or nothing is re-sent).
"""

from __future__ import annotations

import threading
from datetime import timedelta
from typing import Any

import pytest
from sqlalchemy import update

from robobpp.db import work
from robobpp.db.models import EpisodeRow, Submission, utcnow
from robobpp.worker.celery_app import make_celery
from robobpp.worker.celery_executor import CeleryExecutor, queue_length, resend_lost
from robobpp.worker.options import WorkerOptions
from robobpp.worker.tasks import enqueue
from tests.celery.conftest import (
    LEASE_S,
    Fleet,
    _drop_queue,
    cancel_active_submissions,
    episodes,
    new_submission,
    submission_status,
    wait_for,
)

pytestmark = [pytest.mark.postgres, pytest.mark.redis, pytest.mark.rabbitmq]
POLICY = "tests.celery.helpers:PacedDBL"


def _app(fleet: Fleet) -> Any:
    env = fleet.env
    options = WorkerOptions(
        database_url=env["ROBOBPP_DATABASE_URL"],
        groups=4,
        lease_s=LEASE_S,
        spec_provider=env["ROBOBPP_SPEC_PROVIDER"],
        poll_interval_s=0.3,
    )
    return make_celery(env["ROBOBPP_BROKER_URL"], options, queue=env["ROBOBPP_CELERY_QUEUE"])


def _mark_sent(factory: Any, sub: int) -> list[int]:
    """Mark the submission's episodes sent, as the dispatcher does, and return their ids."""
    with factory() as s, s.begin():
        return work.take_unsent(s, stale_after_s=3600, ids=[e.id for e in episodes(factory, sub)])


def _backdate(factory: Any, ids: list[int], seconds: float) -> None:
    with factory() as s, s.begin():
        s.execute(
            update(EpisodeRow)
            .where(EpisodeRow.id.in_(ids))
            .values(enqueued_at=utcnow() - timedelta(seconds=seconds))
        )


def _purge(app: Any) -> None:
    with app.pool.acquire(block=True) as conn:
        conn.default_channel.queue_purge(app.conf.robobpp_queue)


def _wait_for_workers(fleet: Fleet, app: Any, n: int) -> None:
    wait_for(lambda: fleet.answering(app) >= n, 90, f"{n} workers to answer", fleet.logs)


def _assert_recorded_once(factory: Any, sub: int, fleet: Fleet) -> None:
    rows = episodes(factory, sub)
    assert [(r.status, r.attempts) for r in rows] == [("done", 1)] * len(rows), fleet.logs()


def test_a_message_lost_after_its_mark_is_sent_again(fleet: Fleet, factory: Any) -> None:
    """The mark commits but the message never reaches a queue (a broker that lost it): the episode still runs,
    once, although the mark is far younger than the stale-message limit (the visibility timeout)."""
    sub = new_submission(
        factory,
        policy=POLICY,
        datasets=["repetitive"],
        groups=1,
        name=f"lost-{fleet.env['ROBOBPP_CELERY_QUEUE']}",
    )
    marked = _mark_sent(factory, sub)
    assert len(marked) == 1
    app = _app(fleet)
    fleet.start(1)
    _wait_for_workers(fleet, app, 1)
    executor = CeleryExecutor(app)
    executor.start()
    try:
        wait_for(lambda: submission_status(factory, sub) == "completed", 90, "the lost episode", fleet.logs)
    finally:
        executor.stop()
    _assert_recorded_once(factory, sub, fleet)


def test_a_message_reserved_by_a_killed_worker_is_sent_again(fleet: Fleet, factory: Any) -> None:
    """A worker reserves the message (here a delayed one, which Celery holds in memory as it does a retry's)
    and is killed with ``kill -9`` before it claims the episode. Redis keeps that message from every other
    worker until its visibility timeout; RabbitMQ requeues it, and the next worker holds it for its delay.
    Either way the episode is pending and marked sent: the lost-message check sends it again."""
    sub = new_submission(
        factory,
        policy=POLICY,
        datasets=["repetitive"],
        groups=1,
        name=f"reserved-{fleet.env['ROBOBPP_CELERY_QUEUE']}",
    )
    app = _app(fleet)
    (first,) = fleet.start(1)
    _wait_for_workers(fleet, app, 1)
    with factory() as s, s.begin():
        ids = work.take_unsent(s, stale_after_s=3600, ids=[e.id for e in episodes(factory, sub)])
        enqueue(app, ids, countdown=600)
    (episode_id,) = ids
    wait_for(
        lambda: f"episode-{episode_id}] received" in fleet.logs(), 60, "the worker to reserve it", fleet.logs
    )
    assert queue_length(app) == 0
    fleet.kill(first)
    fleet.start(1)
    _wait_for_workers(fleet, app, 1)
    executor = CeleryExecutor(app)
    executor.start()
    try:
        wait_for(
            lambda: submission_status(factory, sub) == "completed", 90, "the reserved episode", fleet.logs
        )
    finally:
        executor.stop()
    _assert_recorded_once(factory, sub, fleet)


def _queued_long_ago(fleet: Fleet, factory: Any, groups: int, name: str) -> tuple[Any, list[int]]:
    """A new submission's episodes sent with no worker to take them, queued, and marked sent ten minutes ago:
    the app that sent them and their ids."""
    sub = new_submission(
        factory,
        policy=POLICY,
        datasets=["repetitive"],
        groups=groups,
        name=f"{name}-{fleet.env['ROBOBPP_CELERY_QUEUE']}",
    )
    app = _app(fleet)
    with factory() as s, s.begin():
        ids = work.take_unsent(s, stale_after_s=3600, ids=[e.id for e in episodes(factory, sub)])
        enqueue(app, ids)
    wait_for(lambda: queue_length(app) == groups, 10, "the messages to be queued", lambda: "")
    _backdate(factory, ids, 600)
    return app, ids


def test_a_backlog_is_not_sent_twice_but_a_drained_queue_is_healed(fleet: Fleet, factory: Any) -> None:
    """No workers: old marks whose messages still wait in the queue are left alone, however old (no
    duplicates from a backlog); once the queue is empty they are sent again, once."""
    app, ids = _queued_long_ago(fleet, factory, 3, "backlog")
    assert resend_lost(factory, app) == []  # a backlog: nothing lost
    assert queue_length(app) == 3
    _purge(app)  # the broker loses them
    assert resend_lost(factory, app) == sorted(ids)
    wait_for(lambda: queue_length(app) == 3, 10, "the re-sent messages to be queued", lambda: "")
    assert resend_lost(factory, app) == []  # their marks are fresh again: sent once
    _purge(app)


def test_a_queue_the_broker_lost_is_declared_again_before_the_lost_messages_are_sent(
    fleet: Fleet, factory: Any
) -> None:
    """The broker forgets the queue itself, messages and all (RabbitMQ restarted without persistence), and no
    worker is back to declare it: the re-sent copy must still reach a queue. RabbitMQ drops a message for a
    queue that does not exist without an error, and the app's producer, which declared the queue once,
    does not declare it again: before the fix every re-send vanished until a worker reconnected (a flaky
    failure of the broker-loss test under load)."""
    app, ids = _queued_long_ago(fleet, factory, 2, "lost-queue")  # the producer declares the queue, once
    _drop_queue(fleet.env["ROBOBPP_BROKER_URL"], fleet.env["ROBOBPP_CELERY_QUEUE"])
    assert resend_lost(factory, app) == sorted(ids)
    wait_for(lambda: queue_length(app) == 2, 10, "the re-sent messages to reach a queue", lambda: "")
    _purge(app)


@pytest.mark.parametrize("broker", ["redis"], indirect=True)
def test_a_claim_by_id_waits_for_the_senders_commit(fleet: Fleet, factory: Any) -> None:
    """The sender publishes inside the transaction that marks the episode; a worker fast enough to get the
    message before that commit must claim the episode, not skip the still-locked row (which used to turn
    the message into a no-op and a delayed copy that a worker holds in memory)."""
    cancel_active_submissions(factory)
    sub = new_submission(
        factory,
        policy=POLICY,
        datasets=["repetitive"],
        groups=1,
        name=f"commit-{fleet.env['ROBOBPP_CELERY_QUEUE']}",
    )
    (row,) = episodes(factory, sub)
    claims: list[Any] = []
    sender = factory()
    sender.begin()
    try:
        marked = work.take_unsent(sender, stale_after_s=3600, ids=[row.id])  # row locked, not committed
        assert marked == [row.id]

        def claim() -> None:
            with factory() as s, s.begin():
                claims.append(
                    work.claim_episode(s, "celery:test:1", lease_s=LEASE_S, max_attempts=3, episode_id=row.id)
                )

        worker = threading.Thread(target=claim)
        worker.start()
        worker.join(1.0)
        assert worker.is_alive() and not claims, f"the claim did not wait for the sender: {claims}"
        sender.commit()
    finally:
        sender.close()
    worker.join(30)
    assert len(claims) == 1 and claims[0] is not None and claims[0].episode_id == row.id
    (after,) = episodes(factory, sub)
    assert (after.status, after.attempts) == ("running", 1)
    with factory() as s, s.begin():  # leave nothing running for the module's other tests
        submission = s.get(Submission, sub)
        assert submission is not None
        work.cancel_submission(s, submission)
