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
    server = make_server(db_url, ROBOBPP_EVALUATE_BASELINES="0", ROBOBPP_GROUPS="6")
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
    server = make_server(db_url, ROBOBPP_EVALUATE_BASELINES="0", ROBOBPP_WORKERS="1")
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
