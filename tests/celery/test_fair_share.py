"""Fair share through a real broker: a second participant starts within one episode-time of submitting, however
many messages of a slow participant wait ahead of its own in the (first come, first served) queue."""

from __future__ import annotations

from datetime import datetime

import pytest

from robobpp.worker.celery_executor import CeleryExecutor
from tests.celery.conftest import Fleet, episode_states, episodes, new_submission, submission_status, wait_for
from tests.celery.test_delivery import _app

pytestmark = [pytest.mark.postgres, pytest.mark.redis, pytest.mark.rabbitmq]


def _seconds(start: datetime | None, end: datetime | None) -> float:
    """How long an episode ran (it started and finished)."""
    assert start is not None and end is not None
    return (end - start).total_seconds()


def test_a_second_participant_starts_within_one_episode_time(own_fleet: Fleet, own_pg_url: str) -> None:
    from robobpp.db.session import make_engine, make_session_factory

    engine = make_engine(own_pg_url)
    factory = make_session_factory(engine)
    fleet = own_fleet
    app = _app(fleet)
    fleet.start(2)
    wait_for(lambda: fleet.answering(app) >= 2, 90, "2 workers to answer", fleet.logs)
    executor = CeleryExecutor(app, ping_every_s=10_000)
    executor.start()
    logs = lambda: fleet.logs() + episode_states(factory)  # noqa: E731
    try:
        slow = new_submission(
            factory,
            policy="tests.celery.helpers:SlowDBL",
            datasets=["repetitive", "diverse"],
            groups=4,
            name="slow",
        )
        wait_for(
            lambda: [e.status for e in episodes(factory, slow)].count("running") == 2,
            90,
            "both workers on the slow participant",
            logs,
        )
        second = new_submission(
            factory, policy="tests.celery.helpers:PacedDBL", datasets=["repetitive"], groups=1, name="second"
        )
        wait_for(
            lambda: submission_status(factory, second) == "completed", 120, "the second participant", logs
        )
        mine = episodes(factory, second)[0]
        with factory() as s:
            from robobpp.db.models import Submission

            submission = s.get(Submission, second)
            assert submission is not None
            submitted = submission.created_at
        assert mine.started_at is not None
        waited = (mine.started_at - submitted).total_seconds()
        wait_for(lambda: any(e.status == "done" for e in episodes(factory, slow)), 60, "a slow episode", logs)
        took = [_seconds(e.started_at, e.finished_at) for e in episodes(factory, slow) if e.finished_at]
        # One episode-time (the longest of the slow participant's, measured here) plus a dispatcher round.
        assert waited <= max(took) + 2.0, (waited, took, logs())
        states = [e.status for e in episodes(factory, slow)]
        assert states.count("pending") >= 4, "first come, first served would have run these first"
    finally:
        executor.stop()
        engine.dispose()
