"""Episodes multiplexed on Celery workers (robobpp/worker/tasks.py, robobpp/worker/nodes.py), with real PostgreSQL,
Redis and ``robobpp worker`` processes: a participant's slow policy does not hold back another participant's fast
submission on the same worker process; ``--concurrency N`` runs N nodes that restart when killed and end with
their supervisor."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any

import pytest

from robobpp.client.serve import BackgroundServer, create_policy_app
from robobpp.core import Action, Observation
from robobpp.db import work
from robobpp.db.models import Participant
from robobpp.policies.dbl import DBL
from robobpp.worker.celery_executor import CeleryExecutor
from tests.celery.conftest import Fleet, episode_states, episodes, submission_status, wait_for
from tests.celery.test_delivery import _app

pytestmark = [pytest.mark.postgres, pytest.mark.redis]
SECRET = "policy-secret-123"


class ThinkingDBL(DBL):
    """A participant's policy that thinks half a second a box: its 16-box episodes last 8 s or more each."""

    def act(self, obs: Observation) -> Action | None:
        time.sleep(0.5)
        return super().act(obs)


def _remote_submission(factory: Any, url: str, name: str, datasets: list[str], groups: int) -> int:
    with factory() as s, s.begin():
        participant = Participant(name=name)
        s.add(participant)
        s.flush()
        return work.create_submission(
            s,
            participant,
            name=name,
            policy_url=url,
            secret=SECRET,
            datasets=datasets,
            settings=["math"],
            groups=groups,
            track="public",
        ).id


@pytest.mark.parametrize("broker", ["redis"], indirect=True)
def test_a_slow_policy_does_not_hold_back_a_fast_submission_on_one_worker_process(
    own_fleet: Fleet, own_pg_url: str
) -> None:
    from robobpp.db.session import make_engine, make_session_factory

    engine = make_engine(own_pg_url)
    factory = make_session_factory(engine)
    fleet = own_fleet
    fleet.env["ROBOBPP_EPISODES_PER_WORKER"] = "8"
    fleet.env["ROBOBPP_PARTICIPANT_MAX_RUNNING"] = "2"
    app = _app(fleet)
    fleet.start(1)  # one worker process: before, one episode at a time
    wait_for(lambda: fleet.answering(app) >= 1, 90, "the worker to answer", fleet.logs)
    executor = CeleryExecutor(app, ping_every_s=10_000)
    executor.start()
    slow_policy = BackgroundServer(create_policy_app(ThinkingDBL, SECRET)).start()
    fast_policy = BackgroundServer(create_policy_app(DBL, SECRET)).start()
    logs = lambda: fleet.logs() + episode_states(factory)  # noqa: E731
    try:
        slow = _remote_submission(factory, slow_policy.url, "slow", ["repetitive", "diverse"], 2)

        def slow_running() -> list[Any]:
            rows = [e for e in episodes(factory, slow) if e.status == "running" and e.step >= 1]
            return rows if len(rows) == 2 else []

        held = wait_for(slow_running, 90, "the slow participant's two episodes in flight", logs)
        assert len({e.worker for e in held}) == 1  # both in the one worker process, waiting on their policy
        fast = _remote_submission(factory, fast_policy.url, "fast", ["repetitive", "diverse"], 2)
        wait_for(lambda: submission_status(factory, fast) == "completed", 120, "the fast submission", logs)
        done = {e.id: e for e in episodes(factory, slow)}
        fast_end = max(e.finished_at for e in episodes(factory, fast) if e.finished_at is not None)
        # Before, the worker process ran one episode at a time: the fast submission's first episode waited for
        # a slow one to end. Now all of it ran while the slow episodes in flight waited on their policy.
        for e in held:
            now = done[e.id]
            assert now.finished_at is None or now.finished_at > fast_end, logs()
        assert {e.worker for e in episodes(factory, fast)} == {held[0].worker}, logs()
        assert all(e.status == "done" and e.attempts == 1 for e in episodes(factory, fast)), logs()
        wait_for(lambda: submission_status(factory, slow) == "completed", 240, "the slow submission", logs)
        assert all(e.attempts == 1 for e in episodes(factory, slow)), logs()  # each recorded once, first try
    finally:
        executor.stop()
        slow_policy.stop()
        fast_policy.stop()
        engine.dispose()


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.parametrize("broker", ["redis"], indirect=True)
def test_concurrency_n_runs_n_nodes_restarted_when_killed_and_ended_with_their_supervisor(
    fleet: Fleet,
) -> None:
    app = _app(fleet)
    (parent,) = fleet.start(1, concurrency=2)
    name, host = fleet.hostnames[parent.pid].split("@")
    nodes = [f"{name}-{i}@{host}" for i in range(2)]

    def pids() -> dict[str, int]:
        stats = app.control.inspect(destination=nodes, timeout=1.0).stats() or {}
        return {node: int(stats[node]["pid"]) for node in nodes if node in stats}

    first = wait_for(lambda: len(p := pids()) == 2 and p, 90, "two nodes to answer", fleet.logs)
    assert parent.pid not in first.values()  # the command supervises; the nodes run the episodes
    os.kill(first[nodes[0]], signal.SIGKILL)  # a node dies (the OOM killer's way): it is started again
    again = wait_for(
        lambda: len(p := pids()) == 2 and p[nodes[0]] != first[nodes[0]] and p,
        60,
        "the node again",
        fleet.logs,
    )
    assert again[nodes[1]] == first[nodes[1]]
    assert "worker node 0" in fleet.logs()
    os.kill(parent.pid, signal.SIGKILL)  # the supervisor dies: no node goes on unsupervised
    parent.wait(10)
    wait_for(lambda: not any(_alive(p) for p in again.values()), 10, "the nodes to end", fleet.logs)


def test_the_supervisor_names_its_nodes_apart() -> None:
    from robobpp.worker.nodes import node_command, node_hostname

    assert [node_hostname("w@h", i) for i in range(2)] == ["w-0@h", "w-1@h"]
    assert node_hostname(None, 3) is None
    cmd = node_command(loglevel="INFO", hostname="w-0@h", parent_pid=42)
    assert cmd[cmd.index("--concurrency") + 1] == "1" and cmd[cmd.index("--parent-pid") + 1] == "42"
