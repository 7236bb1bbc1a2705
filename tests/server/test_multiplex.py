"""Several episodes in flight per worker process (robobpp/worker/multiplex.py), with a real server, real worker
processes and real remote policies: a slow policy no longer holds the pool; a multiplexed worker killed
mid-episode has each of its episodes retried and recorded once; a cancelled submission's in-flight results are
dropped (tests/server/test_faults.py)."""

from __future__ import annotations

import os
import signal
from collections import Counter
from datetime import datetime

from tests.server.conftest import SlowDBL, db_rows, new_participant, wait_for
from tests.server.test_faults import _check_recorded_once, _submit


class ThinkingDBL(SlowDBL):
    delay_s = 1.0  # a second a box: an offline episode of 12 boxes takes about 12 s


def _when(value: object) -> datetime:
    return value if isinstance(value, datetime) else datetime.fromisoformat(str(value))


def _running_by_worker(db_url: str, sid: int, min_step: int = 0) -> Counter[str]:
    rows = db_rows(
        db_url,
        "SELECT worker FROM episodes WHERE submission_id = :s AND status = 'running' AND step >= :m",
        s=sid,
        m=min_step,
    )
    return Counter(w for (w,) in rows)


def test_fast_submission_completes_while_a_slow_policy_occupies_the_workers(
    make_server, policy_server, tmp_path
) -> None:
    db_url = f"sqlite:///{tmp_path / 'mux.sqlite3'}"
    # 4 episodes of a participant at once (the default is 1): they fill one-episode-per-worker's 2 workers
    server = make_server(
        db_url, ROBOBPP_EVALUATE_BASELINES="0", ROBOBPP_GROUPS="6", ROBOBPP_PARTICIPANT_MAX_RUNNING="4"
    )
    admin = server.client()
    slow = server.client(new_participant(admin, "slow"))
    fast = server.client(new_participant(admin, "fast"))
    many = _submit(slow, policy_server(ThinkingDBL), ["diverse", "repetitive"])  # 12 episodes of ~12 s
    # the participant's limit (4) is reached on the two workers: one-episode-per-worker would be full
    wait_for(lambda: sum(_running_by_worker(db_url, many).values()) == 4, timeout_s=60, every_s=0.1)
    sid = _submit(fast, policy_server(), ["diverse"])  # 6 episodes of a fast policy
    done = wait_for(
        lambda: (s := fast.get(f"/submissions/{sid}").json())["status"] == "completed" and s, timeout_s=60
    )
    assert done["progress"]["episodes_done"] == 6
    (created, finished) = db_rows(
        db_url, "SELECT created_at, finished_at FROM submissions WHERE id = :s", s=sid
    )[0]
    took = (_when(finished) - _when(created)).total_seconds()
    # one episode per worker made it wait for a slow episode to end (about 12 s) before its first started
    assert took < 10, took
    assert slow.get(f"/submissions/{many}").json()["status"] == "running"
    # the slow episodes were in flight beside the fast ones, and kept running
    assert sum(_running_by_worker(db_url, many).values()) >= 1


def test_killed_multiplexed_worker_episodes_are_retried_and_recorded_once(
    make_server, policy_server, tmp_path
) -> None:
    db_url = f"sqlite:///{tmp_path / 'kill.sqlite3'}"
    server = make_server(
        db_url, ROBOBPP_EVALUATE_BASELINES="0", ROBOBPP_WORKERS="1", ROBOBPP_PARTICIPANT_MAX_RUNNING="4"
    )
    client = server.client(new_participant(server.client()))
    sid = _submit(client, policy_server(SlowDBL), ["diverse", "repetitive"])  # 4 episodes, all in one worker
    worker, held = wait_for(
        lambda: next(((w, n) for w, n in _running_by_worker(db_url, sid, 2).items() if n >= 2), None),
        every_s=0.1,
    )
    victims = [
        i
        for (i,) in db_rows(
            db_url,
            "SELECT id FROM episodes WHERE submission_id = :s AND worker = :w AND status = 'running'",
            s=sid,
            w=worker,
        )
    ]
    assert len(victims) >= held >= 2
    os.kill(int(worker.rsplit(":", 1)[1]), signal.SIGKILL)
    _check_recorded_once(client, db_url, sid, ["diverse", "repetitive"])
    attempts = db_rows(db_url, "SELECT id, attempts FROM episodes WHERE submission_id = :s", s=sid)
    assert all(a == 2 for i, a in attempts if i in victims), attempts


def _multiplexer(tmp_path, policy_url: str, runner, limit: int = 4):
    """A worker's multiplexer on a fresh SQLite database with one submission of 4 Math episodes."""
    from robobpp.db import work
    from robobpp.db.migrate import upgrade
    from robobpp.db.models import Participant
    from robobpp.db.session import make_engine, make_session_factory, transaction
    from robobpp.worker.multiplex import Multiplexer
    from robobpp.worker.options import WorkerOptions

    url = f"sqlite:///{tmp_path / 'rule.sqlite3'}"
    engine = make_engine(url)
    upgrade(url, engine=engine)
    factory = make_session_factory(engine)
    with transaction(factory) as s:
        p = Participant(name="p")
        s.add(p)
        s.flush()
        work.create_submission(
            s, p, name="x", policy_url=policy_url, datasets=["diverse"], settings=["math"], groups=4
        )
    options = WorkerOptions(database_url=url, episodes_per_worker=limit, participant_max_running=10)
    return Multiplexer(factory, options, "local:test:1", runner=runner)


def test_a_further_episode_is_claimed_only_while_every_one_in_flight_waits(tmp_path) -> None:
    """The rule without a server: an episode that computes (a built-in's, a replay) keeps the CPU and no other is
    claimed beside it; one that waits on its policy lets another be claimed, up to the per-process bound."""
    import threading

    release = threading.Event()

    def computes(factory, claim, options, gate) -> bool:
        release.wait(10)
        return True

    mux = _multiplexer(tmp_path, "builtin:dbl", computes)
    assert mux.claim_next(1.0) is True
    assert mux.claim_next(0.3) is False and mux.in_flight() == 1  # the CPU stays busy: nothing claimed
    release.set()
    assert mux.drain(10)

    release.clear()

    def waits(factory, claim, options, gate) -> bool:
        with gate.waiting():
            release.wait(10)
        return True

    (tmp_path / "w").mkdir()
    mux = _multiplexer(tmp_path / "w", "http://policy.example", waits, limit=3)
    assert [mux.claim_next(1.0) for _ in range(3)] == [True, True, True]
    assert mux.claim_next(0.3) is False and mux.in_flight() == 3  # the per-process bound
    release.set()
    assert mux.drain(10) and mux.claim_next(1.0) is True  # the fourth episode, once room is back
    assert mux.drain(10)
