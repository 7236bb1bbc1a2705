"""The Celery executor against the machine's real Redis / RabbitMQ and PostgreSQL, with real worker
processes (``robobpp worker``): draining, surviving ``kill -9``, and agreeing with the local executor."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from robobpp.boards.engine import leaderboard
from robobpp.db.models import EpisodeRow, RunRow
from robobpp.episode import run_episode
from robobpp.policies import load_policy
from robobpp.worker.celery_app import make_celery
from robobpp.worker.celery_executor import CeleryExecutor
from robobpp.worker.options import WorkerOptions
from tests.celery.conftest import (
    LEASE_S,
    Fleet,
    episode_states,
    episodes,
    new_submission,
    submission_status,
    wait_for,
)
from tests.celery.helpers import spec

pytestmark = [pytest.mark.postgres, pytest.mark.redis, pytest.mark.rabbitmq]
GEOMETRY = ("space_utilization", "occupancy")  # wall clock never decides these


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


def _start(fleet: Fleet, workers: int) -> tuple[Any, CeleryExecutor]:
    """Workers first (and answering), then the server-side dispatcher, so every worker competes."""
    fleet.start(workers)
    app = _app(fleet)
    wait_for(lambda: fleet.answering(app) >= workers, 90, f"{workers} workers to answer", fleet.logs)
    executor = CeleryExecutor(app)
    executor.start()
    return app, executor


def _expected(dataset: str, group: int, policy: str) -> dict[str, Any]:
    """The episode run directly through the one episode loop, in this process."""
    return run_episode(spec(dataset, "train", group, 4), load_policy(policy), "math").to_dict(trace=False)


def _completed(factory: Any, submission_id: int) -> Callable[[], bool]:
    return lambda: submission_status(factory, submission_id) == "completed"


def test_two_workers_drain_a_submission(fleet: Fleet, factory: Any) -> None:
    sub = new_submission(
        factory,
        policy="tests.celery.helpers:PacedDBL",
        datasets=["repetitive", "diverse"],
        groups=3,
        name=f"drain-{fleet.env['ROBOBPP_CELERY_QUEUE']}",
    )
    _app_, executor = _start(fleet, 2)
    try:
        wait_for(lambda: submission_status(factory, sub) == "completed", 120, "the submission", fleet.logs)
    finally:
        executor.stop()
    rows = episodes(factory, sub)
    assert len(rows) == 6
    assert all(r.status == "done" and r.attempts == 1 for r in rows), [(r.status, r.attempts) for r in rows]
    processes = {r.worker for r in rows}
    assert len(processes) == 2, f"both workers should have run episodes: {processes}\n{fleet.logs()}"
    for r in rows:
        want = _expected(r.dataset, r.group, "tests.celery.helpers:PacedDBL")
        assert r.termination == want["termination"]
        assert r.boxes_placed == want["boxes_placed"]
        assert r.metrics is not None
        for key in GEOMETRY:
            assert r.metrics[key] == pytest.approx(want["metrics"][key], abs=1e-12)


def test_kill_9_mid_episode_completes_once_on_the_other_worker(fleet: Fleet, factory: Any) -> None:
    sub = new_submission(
        factory,
        policy="tests.celery.helpers:SlowDBL",
        datasets=["repetitive"],
        groups=1,
        name=f"kill-{fleet.env['ROBOBPP_CELERY_QUEUE']}",
    )
    app, executor = _start(fleet, 2)
    try:

        def running() -> EpisodeRow | None:
            (row,) = episodes(factory, sub)
            return row if row.status == "running" and row.step >= 2 else None

        row = wait_for(running, 90, "the episode to be mid-way", fleet.logs)
        victim_pid = int(row.worker.rsplit(":", 1)[1])
        import os

        victim_group = os.getpgid(victim_pid)
        victim = next(p for p in fleet.procs if p.pid == victim_group)
        fleet.kill(victim)  # kill -9 of the whole worker: main process and its pool child
        wait_for(
            lambda: submission_status(factory, sub) == "completed",
            120,
            "the retried episode",
            lambda: f"{episode_states(factory, sub)}\n{fleet.logs()}",
        )
        (done,) = episodes(factory, sub)
        seen = (done.status, done.attempts, done.worker, row.worker)
        assert done.status == "done", f"{seen}\n{fleet.logs()}"
        assert done.attempts == 2, f"{seen}\n{fleet.logs()}"
        assert done.worker != row.worker
        want = _expected("repetitive", 0, "tests.celery.helpers:SlowDBL")
        assert done.termination == want["termination"]
        assert done.trace is not None and done.metrics is not None
        assert done.boxes_placed == want["boxes_placed"] == len(done.trace["steps"])
        for key in GEOMETRY:
            assert done.metrics[key] == pytest.approx(want["metrics"][key], abs=1e-12)
        with factory() as s:
            (run,) = s.execute(select(RunRow).where(RunRow.submission_id == sub)).scalars()
        assert run.status == "completed" and run.extras["episodes"] == 1

        # A redelivered copy of the message (what Redis does after its visibility timeout) changes nothing.
        from robobpp.worker.tasks import execute

        assert execute(app, done.id, worker="celery:redelivery:1") == "skipped"
        (again,) = episodes(factory, sub)
        assert (again.finished_at, again.attempts, again.worker, again.metrics) == (
            done.finished_at,
            done.attempts,
            done.worker,
            done.metrics,
        )
    finally:
        executor.stop()


@pytest.mark.parametrize("broker", ["redis"], indirect=True)
def test_leaderboard_equals_the_local_executor(fleet: Fleet, factory: Any, tmp_path: Path) -> None:
    from robobpp.db.migrate import upgrade
    from robobpp.db.session import make_engine, make_session_factory
    from robobpp.worker.local import LocalExecutor

    policies = ("tests.celery.helpers:PacedDBL", "random")
    tag = fleet.env["ROBOBPP_CELERY_QUEUE"]
    celery_subs = [
        new_submission(factory, policy=p, datasets=["repetitive"], groups=3, name=f"{tag}-{i}")
        for i, p in enumerate(policies)
    ]
    _app_, executor = _start(fleet, 2)
    try:
        for sub in celery_subs:
            wait_for(_completed(factory, sub), 120, "celery run", fleet.logs)
    finally:
        executor.stop()

    local_url = f"sqlite:///{tmp_path / 'local.sqlite3'}"
    upgrade(local_url)
    local = make_session_factory(make_engine(local_url))
    local_subs = [
        new_submission(local, policy=p, datasets=["repetitive"], groups=3, name=f"{tag}-{i}")
        for i, p in enumerate(policies)
    ]
    pool = LocalExecutor(
        WorkerOptions(
            database_url=local_url,
            groups=4,
            lease_s=LEASE_S,
            poll_interval_s=0.2,
            spec_provider="tests.celery.helpers:spec",
        ),
        2,
    )
    pool.start()
    try:
        for sub in local_subs:
            wait_for(_completed(local, sub), 120, "local run", lambda: "")
    finally:
        pool.stop()

    def board(f: Any, subs: list[int]) -> list[tuple[str, dict[str, Any], dict[str, Any]]]:
        with f() as s:
            entries = leaderboard(s, "repetitive", "math", track="public").entries
        mine = [e for e in entries if e["submission_id"] in subs]
        assert len(mine) == len(subs)
        return [
            (e["name"], {k: v for k, v in e["metrics"].items() if k != "decision_time"}, e["extras"])
            for e in mine
        ]

    assert board(factory, celery_subs) == board(local, local_subs)


@pytest.mark.parametrize("broker", ["redis"], indirect=True)
def test_the_server_dispatches_to_celery_when_a_broker_is_set(own_fleet: Fleet, tmp_path: Path) -> None:
    """End to end: baselines queued at first start and a submission made through the API both run on the
    Celery workers; the server itself runs no local pool.

    The server gets a database of its own: it dispatches every pending episode of its database and its API
    lists every submission in it, so in the module's shared database one unfinished submission of an earlier
    test (a failed kill test) kept this test waiting although its own work was all recorded."""
    from robobpp.db.session import make_engine, make_session_factory

    engine = make_engine(own_fleet.env["ROBOBPP_DATABASE_URL"])
    try:
        _serve_and_check(own_fleet, make_session_factory(engine), tmp_path)
    finally:
        engine.dispose()


def _serve_and_check(fleet: Fleet, own: Any, tmp_path: Path) -> None:
    from fastapi.testclient import TestClient

    from robobpp.server.app import create_app
    from robobpp.server.config import Settings
    from robobpp.worker.celery_executor import CeleryExecutor as Dispatcher

    env = fleet.env
    settings = Settings(
        database_url=env["ROBOBPP_DATABASE_URL"],
        broker_url=env["ROBOBPP_BROKER_URL"],
        celery_queue=env["ROBOBPP_CELERY_QUEUE"],
        spec_provider=env["ROBOBPP_SPEC_PROVIDER"],
        state_dir=tmp_path / "server",
        datasets=("repetitive",),
        settings=("math",),
        groups=2,
        baselines=("dbl",),
        lease_s=LEASE_S,
        poll_interval_s=0.3,
        admin_token="a-strong-admin-token-0123",
    )
    fleet.start(2)
    with TestClient(create_app(settings)) as client:
        assert isinstance(client.app.state.runtime.executor, Dispatcher)  # type: ignore[attr-defined]
        auth = {"Authorization": "Bearer a-strong-admin-token-0123"}
        made = client.post(
            "/api/v1/submissions",
            headers=auth,
            json={"name": "random-run", "policy_url": "builtin:random", "track": "public"},
        )
        assert made.status_code == 201, made.text

        def finished() -> bool:  # the baselines queued at start and the API's submission: all it holds
            subs = client.get("/api/v1/submissions", headers=auth).json()
            return len(subs) >= 2 and all(s["status"] == "completed" for s in subs)

        wait_for(
            finished,
            120,
            "baseline and submission on the workers",
            lambda: f"{episode_states(own)}\n{fleet.logs()}",
        )
        health = client.get("/healthz").json()
        assert health["status"] == "ok"
    with own() as s:
        ran = s.execute(select(EpisodeRow.status, EpisodeRow.worker)).all()
    assert len(ran) >= 4 and all(st == "done" and w.startswith("celery:") for st, w in ran), ran


def test_celery_workers_replay_math_episodes_under_the_paper_protocol(fleet: Fleet, factory: Any) -> None:
    """A submission with Math Pack and Physics Pack: the Celery workers run its replays too, each a message of
    its own once its Math episode is recorded, each recorded once, with exactly the Math actions."""
    from robobpp.db import work
    from robobpp.db.models import Participant

    name = f"paper-{fleet.env['ROBOBPP_CELERY_QUEUE']}"
    with factory() as s, s.begin():
        participant = Participant(name=name)
        s.add(participant)
        s.flush()
        sub = work.create_submission(
            s,
            participant,
            name=name,
            policy_url="builtin:tests.celery.helpers:PacedDBL",
            datasets=["diverse"],
            settings=["math", "physics"],
            groups=2,
            track="public",
        ).id
    _app_, executor = _start(fleet, 2)
    try:
        wait_for(
            lambda: submission_status(factory, sub) == "completed",
            180,
            "the submission",
            lambda: episode_states(factory, sub) + "\n" + fleet.logs(),
        )
    finally:
        executor.stop()
    rows = episodes(factory, sub)
    assert sorted((r.setting, r.protocol) for r in rows) == sorted(
        [("math", "closed")] * 2 + [("physics", "closed")] * 2 + [("physics", "paper")] * 2
    )
    assert all(r.status == "done" and r.attempts == 1 for r in rows), episode_states(factory, sub)
    for replay in (r for r in rows if r.protocol == "paper"):
        assert (replay.worker or "").startswith("celery:")
        with factory() as s:
            assert work.episode_plan(s, replay.id) is None  # spent
        math = next(r for r in rows if (r.setting, r.group) == ("math", replay.group))
        assert replay.trace is not None and math.trace is not None
        played = [(st["action"], st["decision_time"]) for st in replay.trace["steps"]]
        assert (
            played
            and played == [(st["action"], st["decision_time"]) for st in math.trace["steps"]][: len(played)]
        )
