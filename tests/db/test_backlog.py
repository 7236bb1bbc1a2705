"""The backlog's expected end counts places: a worker keeps ``per_worker`` participants' episodes in flight (they
wait on their policies), while a built-in's episode holds the whole worker."""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime, timedelta
from typing import Any

import pytest
from sqlalchemy import select

from robobpp.db import waiting, work
from robobpp.db.migrate import upgrade
from robobpp.db.models import EpisodeRow, Participant, Submission, utcnow
from robobpp.db.session import make_engine, make_session_factory, transaction
from robobpp.server.services.progress import backlog_line


@pytest.fixture
def factory(db_url: str) -> Any:
    engine = make_engine(db_url)
    upgrade(db_url, engine=engine)
    yield make_session_factory(engine)
    engine.dispose()


REMOTE = "http://127.0.0.1:9/policy"


def _submit(s: Any, who: str, *, builtin: bool, groups: int, url: str) -> Submission:
    p = s.execute(select(Participant).where(Participant.name == who)).scalar_one_or_none()
    if p is None:
        p = Participant(name=who, is_builtin=builtin)
        s.add(p)
        s.flush()
    return work.create_submission(
        s, p, name=f"{who}-{groups}", policy_url=url, datasets=["diverse"], settings=["math"], groups=groups
    )


def _finished(s: Any, seconds: Sequence[float], now: datetime) -> None:
    """A finished submission whose episodes took ``seconds`` each (what the mean episode time is read from)."""
    past = _submit(s, "past", builtin=False, groups=len(seconds), url=REMOTE)
    past.status = "completed"
    episodes = s.execute(select(EpisodeRow).where(EpisodeRow.submission_id == past.id)).scalars()
    for took, e in zip(seconds, episodes, strict=True):
        e.status, e.started_at = "done", now - timedelta(seconds=100)
        e.finished_at = e.started_at + timedelta(seconds=took)


def test_the_expected_end_shares_the_pool_places_between_participants_and_built_ins(factory: Any) -> None:
    now = utcnow()
    with transaction(factory) as s:
        _finished(s, (10, 20), now)  # the mean episode: 15 s
        _submit(s, "alice", builtin=False, groups=6, url=REMOTE)  # 6 episodes, a place each
        _submit(s, "robobpp", builtin=True, groups=3, url="builtin:dbl")  # 3 episodes, a whole worker each
    with factory() as s:
        one = waiting.backlog(s, workers=2, now=now)
        four = waiting.backlog(s, workers=2, now=now, per_worker=4)
    assert one is not None and four is not None
    assert one.episodes_left == four.episodes_left == 9 and one.mean_episode_s == 15.0
    # one episode per worker: 9 episodes on 2 workers, 5 rounds of 15 s
    assert one.expected_s == math.ceil(9 / 2) * 15.0
    # 4 places per worker: alice's 6 take 6 places, the built-in's 3 take 4 each: 18 places on 8, 3 rounds
    assert four.expected_s == math.ceil((6 + 3 * 4) / (2 * 4)) * 15.0 == 45.0
    assert four.expected_end == now + timedelta(seconds=45)
    assert "on 2 worker(s) of 4 places each)" in backlog_line(four, 2, 4)
    assert backlog_line(one, 2).endswith("on 2 worker(s))")


def test_running_submissions_count_their_episodes_left_in_places_too(factory: Any) -> None:
    now = utcnow()
    with transaction(factory) as s:
        _finished(s, (10,), now)
        _submit(s, "robobpp", builtin=True, groups=4, url="builtin:dbl")
    with transaction(factory) as s:  # the built-in's first episode claimed: it runs, 4 episodes left
        claim = work.claim_episode(s, "w0", lease_s=60, max_attempts=3)
        assert claim is not None
    with transaction(factory) as s:
        _submit(s, "alice", builtin=False, groups=4, url=REMOTE)
    with factory() as s:
        b = waiting.backlog(s, workers=1, now=now, per_worker=4)
    assert b is not None and b.running == 1 and b.queued == 1
    assert b.episodes_left == 8 and b.episodes_running == 1
    # the built-in's 4 episodes hold the worker's 4 places each, alice's 4 one each: 20 places on 4, 5 rounds
    assert b.expected_s == 5 * 10.0
