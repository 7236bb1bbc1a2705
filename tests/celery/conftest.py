"""Real services for the Celery tests: a fresh PostgreSQL database and a fresh broker queue per run.

Workers are real ``robobpp worker`` subprocesses, each in its own session so ``kill -9`` of one takes its
whole process tree (main process and pool children), like a machine that vanishes.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from robobpp.db import work
from robobpp.db.migrate import upgrade
from robobpp.db.models import EpisodeRow, Participant, Submission
from robobpp.db.session import make_engine, make_session_factory
from robobpp.vocabulary import ACTIVE_SUBMISSION

ROOT = Path(__file__).resolve().parents[2]
PG_ADMIN = "postgresql://postgres@127.0.0.1:5432/test"
BROKERS = {"redis": "redis://127.0.0.1:6379/0", "rabbitmq": "amqp://guest:guest@127.0.0.1:5672//"}
#: Short enough to retry quickly, long enough that a heartbeat (every third of it) survives a loaded machine.
LEASE_S = 5.0


def _reachable(host: str, port: int) -> bool:
    import socket

    try:
        with socket.create_connection((host, port), timeout=1):
            return True
    except OSError:
        return False


@contextlib.contextmanager
def _fresh_database() -> Iterator[str]:
    if not _reachable("127.0.0.1", 5432):
        pytest.skip("PostgreSQL is not running at 127.0.0.1:5432")
    import psycopg

    name = f"robobpp_celery_{uuid.uuid4().hex[:10]}"
    with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    url = f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}"
    try:
        upgrade(url)
        yield url
    finally:
        with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture(scope="module")
def pg_url() -> Iterator[str]:
    """One database for a module's tests (each test makes its own submissions in it)."""
    with _fresh_database() as url:
        yield url


@pytest.fixture
def own_pg_url() -> Iterator[str]:
    """A database for one test alone: for a server, which dispatches every pending episode of its database
    and whose API lists every submission in it, so another test's leftovers must not be there."""
    with _fresh_database() as url:
        yield url


@pytest.fixture(params=["redis", "rabbitmq"])
def broker(request: pytest.FixtureRequest) -> Iterator[tuple[str, str]]:
    """(broker URL, a queue name no other run uses); the queue and its bookkeeping are removed after."""
    kind = request.param
    port = 6379 if kind == "redis" else 5672
    if not _reachable("127.0.0.1", port):
        pytest.skip(f"{kind} is not running at 127.0.0.1:{port}")
    url, queue = BROKERS[kind], f"robobpp-test-{uuid.uuid4().hex[:10]}"
    yield url, queue
    _drop_queue(url, queue)


def _drop_queue(url: str, queue: str) -> None:
    from kombu.connection import Connection

    with Connection(url) as conn:
        with contextlib.suppress(Exception):  # already gone
            conn.default_channel.queue_delete(queue)
        with contextlib.suppress(Exception):
            conn.default_channel.exchange_delete(queue)
        if url.startswith("redis"):
            client = conn.default_channel.client
            client.delete(
                queue,
                f"unacked:{queue}",
                f"unacked_index:{queue}",
                f"unacked_mutex:{queue}",
                f"_kombu.binding.{queue}",
                f"_kombu.binding_permanent.{queue}",
            )


class Fleet:
    """Worker subprocesses against one database and one queue."""

    def __init__(self, pg_url: str, broker_url: str, queue: str, tmp: Path) -> None:
        self.env = {
            **{k: v for k, v in os.environ.items() if not k.startswith("ROBOBPP_")},
            "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
            "ROBOBPP_ENV": "dev",
            "ROBOBPP_STATE_DIR": str(tmp / "data"),
            "ROBOBPP_DATABASE_URL": pg_url,
            "ROBOBPP_BROKER_URL": broker_url,
            "ROBOBPP_CELERY_QUEUE": queue,
            "ROBOBPP_SPEC_PROVIDER": "tests.celery.helpers:spec",
            "ROBOBPP_LEASE_S": str(LEASE_S),
            "ROBOBPP_MAX_ATTEMPTS": "3",
            "ROBOBPP_POLL_INTERVAL_S": "0.3",
            "ROBOBPP_GROUPS": "4",
        }
        self.tmp = tmp
        self.procs: list[subprocess.Popen[bytes]] = []
        self.hostnames: dict[int, str] = {}  # pid → Celery node name

    def start(self, n: int = 2, concurrency: int = 1) -> list[subprocess.Popen[bytes]]:
        new = []
        for i in range(n):
            log = open(self.tmp / f"worker-{len(self.procs)}.log", "wb")  # noqa: SIM115 - closed with the process
            hostname = f"w{len(self.procs)}-{uuid.uuid4().hex[:6]}@test"
            cmd = [
                sys.executable,
                "-c",
                "from robobpp.cli import main; main()",
                "worker",
                "--concurrency",
                str(concurrency),
                "--loglevel",
                "info",
                "--hostname",
                hostname,
            ]
            proc = subprocess.Popen(
                cmd, env=self.env, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
            )
            self.procs.append(proc)
            self.hostnames[proc.pid] = hostname
            new.append(proc)
            del i
        return new

    def answering(self, app: Any) -> int:
        """How many of *this fleet's* live workers answer a ping. The control channel is shared by every worker
        on the broker (other tests' and other runs' too), so a plain ping count can be met by strangers."""
        mine = [self.hostnames[p.pid] for p in self.procs if p.poll() is None]
        if not mine:
            return 0
        try:
            replies = app.control.ping(destination=mine, timeout=0.5) or []
        except Exception:  # noqa: BLE001 - broker not reachable yet
            return 0
        return sum(1 for reply in replies for name in reply if name in mine)

    def kill(self, proc: subprocess.Popen[bytes]) -> None:
        """``kill -9`` of the worker's whole process group."""
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)

    def logs(self) -> str:
        return "\n".join(
            f"--- {p.name}\n" + p.read_text(errors="replace")[-3000:]
            for p in sorted(self.tmp.glob("worker-*.log"))
        )

    def stop(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
        for proc in self.procs:
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)


@pytest.fixture
def fleet(pg_url: str, broker: tuple[str, str], tmp_path: Path) -> Iterator[Fleet]:
    f = Fleet(pg_url, *broker, tmp_path)
    yield f
    f.stop()


@pytest.fixture
def own_fleet(own_pg_url: str, broker: tuple[str, str], tmp_path: Path) -> Iterator[Fleet]:
    """Workers on a database of this test's own (``own_pg_url``)."""
    f = Fleet(own_pg_url, *broker, tmp_path)
    yield f
    f.stop()


def new_submission(factory: Any, *, policy: str, datasets: list[str], groups: int, name: str) -> int:
    with factory() as s, s.begin():
        participant = s.execute(select(Participant).where(Participant.name == name)).scalar_one_or_none()
        if participant is None:
            participant = Participant(name=name)
            s.add(participant)
            s.flush()
        sub = work.create_submission(
            s,
            participant,
            name=name,
            policy_url=f"builtin:{policy}",
            datasets=datasets,
            settings=["math"],
            groups=groups,
            track="public",
        )
        return sub.id


def cancel_active_submissions(factory: Any) -> None:
    """Cancel what the module's earlier tests left unfinished: a Celery message is a ticket for the fairest
    episode with one out, so a claim by id may take a leftover instead of the test's own episode."""
    with factory() as s, s.begin():
        for left in s.execute(select(Submission).where(Submission.status.in_(ACTIVE_SUBMISSION))).scalars():
            work.cancel_submission(s, left)


def wait_for(predicate: Callable[[], Any], timeout: float, what: str, logs: Callable[[], str]) -> Any:
    """Poll until ``predicate`` is truthy (a deadline against hangs, not a timing assertion)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.2)
    pytest.fail(f"timed out waiting for {what}\n{logs()}")


def episodes(factory: Any, submission_id: int) -> list[EpisodeRow]:
    with factory() as s:
        return list(
            s.execute(
                select(EpisodeRow).where(EpisodeRow.submission_id == submission_id).order_by(EpisodeRow.id)
            ).scalars()
        )


def episode_states(factory: Any, submission_id: int | None = None) -> str:
    """The episodes' bookkeeping, one line each: what a timed-out wait needs to tell a lost message (pending,
    marked sent) from a lease that kept expiring (attempts) or a worker that never finished (running)."""
    query = select(EpisodeRow).order_by(EpisodeRow.id)
    if submission_id is not None:
        query = query.where(EpisodeRow.submission_id == submission_id)
    with factory() as s:
        rows = s.execute(query).scalars().all()
        return "\n".join(
            f"episode {r.id} (submission {r.submission_id}): {r.status} attempts={r.attempts} step={r.step} "
            f"worker={r.worker} enqueued_at={r.enqueued_at} lease_expires_at={r.lease_expires_at} "
            f"termination={r.termination}"
            for r in rows
        )


def submission_status(factory: Any, submission_id: int) -> str:
    with factory() as s:
        return s.execute(select(Submission.status).where(Submission.id == submission_id)).scalar_one()


@pytest.fixture(scope="module")
def factory(pg_url: str) -> Iterator[Any]:
    engine = make_engine(pg_url)
    yield make_session_factory(engine)
    engine.dispose()
