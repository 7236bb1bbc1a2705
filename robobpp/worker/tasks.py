"""The Celery task: one message = one episode row id, run by the shared execution unit.

The task adds no evaluation logic of its own. A message is a ticket for one claim through the same SQL lease
as the local executor (:func:`robobpp.db.work.claim_episode`): the fairest episode that has a message out,
its own when no other is free, so the broker's first-come order does not decide who runs first. It runs the
claim with the same unit (:func:`robobpp.worker.run.run_claimed`), which records the result under the lease.
A copy of a message — redelivered by the broker after a worker died, or re-enqueued by a sweeper — claims
early what another message would have claimed, or finds nothing to do and acknowledges itself.
"""

from __future__ import annotations

import logging
import os
import threading
from typing import Any

from celery import Celery
from sqlalchemy import Engine, update
from sqlalchemy.orm import Session, sessionmaker

from robobpp.db import work
from robobpp.db.models import EpisodeRow, utcnow
from robobpp.db.session import make_engine, make_session_factory
from robobpp.worker.celery_names import TASK_NAME, options_of, queue_of, task_id
from robobpp.worker.multiplex import Cpu, process_cpu
from robobpp.worker.options import WorkerOptions
from robobpp.worker.run import run_claimed, worker_id

log = logging.getLogger("robobpp.worker.celery")

#: Seconds before an episode that the unit handed back for a retry (infrastructure error) is sent again.
RETRY_DELAY_S = 5
#: Seconds a task waits for its process's CPU before it sends its message back to the queue: long enough that a
#: node's threads do not churn messages while a built-in's episode computes, short enough that a ticket held
#: here reaches an idle worker process soon.
CPU_WAIT_S = 5.0

# One engine per (process, database): prefork children must never share the parent's sockets.
_engines: dict[tuple[int, str], tuple[Engine, sessionmaker[Session]]] = {}
_engines_lock = threading.Lock()


def session_factory(database_url: str) -> sessionmaker[Session]:
    key = (os.getpid(), database_url)
    with _engines_lock:
        if key not in _engines:
            engine = make_engine(database_url)
            _engines[key] = (engine, make_session_factory(engine))
        return _engines[key][1]


def forget_inherited_engines() -> None:
    """In a freshly forked child: drop the parent's engines without closing the parent's connections."""
    with _engines_lock:
        for (pid, url), (engine, _f) in list(_engines.items()):
            if pid != os.getpid():
                engine.dispose(close=False)
                del _engines[(pid, url)]


def parse_episode_id(value: Any) -> int:
    """Messages come from a shared broker: accept a positive integer id and nothing else."""
    if isinstance(value, bool) or not isinstance(value, int | str):
        raise ValueError(f"episode id must be an integer, got {type(value).__name__}")
    text = str(value).strip()
    if not text.isdigit() or len(text) > 12 or int(text) < 1:
        raise ValueError(f"episode id must be a positive integer, got {str(value)[:40]!r}")
    return int(text)


def enqueue(app: Celery, episode_ids: list[int], *, countdown: float | None = None) -> int:
    """Send one message per episode, its task id derived from the episode id. Returns how many were sent."""
    queue = queue_of(app)
    for episode_id in episode_ids:
        app.send_task(
            TASK_NAME, args=[int(episode_id)], task_id=task_id(episode_id), queue=queue, countdown=countdown
        )
    return len(episode_ids)


def execute(app: Celery, episode_id: int, worker: str | None = None) -> str:
    """Claim and run one episode. Returns what happened: ``recorded``, ``dropped``, ``skipped`` or
    ``deferred`` (the process's CPU stayed busy: the ticket went back to the queue).

    Several of these run at once in one worker process (a node's pool of ``episodes_per_worker`` threads), under
    the rule of the local pool (robobpp/worker/multiplex.py): the task takes its process's CPU before it claims,
    so it claims only while every episode in flight there waits on its participant's policy, and the episode
    holds the CPU except while it waits on that policy."""
    options = options_of(app)
    factory = session_factory(options.database_url)
    me = worker or worker_id("celery")
    cpu = process_cpu()
    if not cpu.acquire(CPU_WAIT_S):
        # An episode of this process computes (a built-in's, a replay, a busy stretch of fast policies): the
        # message is a ticket any worker may use, so it goes back to the queue rather than wait here while
        # another worker process may idle. It is this message sent again, whatever its episode's state, so
        # the tickets out stay as many as before; a pending episode's mark is renewed with it (not "lost").
        with factory() as s, s.begin():
            s.execute(
                update(EpisodeRow)
                .where(EpisodeRow.id == episode_id, EpisodeRow.status == "pending")
                .values(enqueued_at=utcnow())
            )
            enqueue(app, [episode_id])
        log.debug(
            "episode %s: this process's CPU stayed busy %.0f s; message sent again", episode_id, CPU_WAIT_S
        )
        return "deferred"
    try:
        return _claim_and_run(app, options, factory, me, episode_id, cpu)
    finally:
        cpu.release()


def _claim_and_run(
    app: Celery, options: WorkerOptions, factory: sessionmaker[Session], me: str, episode_id: int, cpu: Cpu
) -> str:
    with factory() as s, s.begin():
        claim = work.claim_episode(
            s,
            me,
            lease_s=options.lease_s,
            max_attempts=options.max_attempts,
            episode_id=episode_id,
            max_running_per_participant=options.participant_max_running,
        )
        if claim is None:
            # Still pending means its participant already has its share of episodes running: send it again
            # later (this message is acknowledged). Otherwise it is done, cancelled, failed, unknown, or
            # leased by a live worker; the sweeper re-sends it if that lease ever expires.
            s.execute(
                update(EpisodeRow)
                .where(EpisodeRow.id == episode_id, EpisodeRow.status == "pending")
                .values(enqueued_at=None)
            )
            later = work.take_unsent(s, stale_after_s=0, ids=[episode_id])
            enqueue(app, later, countdown=RETRY_DELAY_S)
    if claim is None:
        log.info(
            "episode %s: nothing to do here (%s)",
            episode_id,
            "its participant is at its limit; sent again later"
            if later
            else "finished or held by another worker",
        )
        return "skipped"
    log.info(
        "episode %s: attempt %s on %s (message for episode %s)",
        claim.episode_id,
        claim.attempt,
        me,
        episode_id,
    )
    if run_claimed(factory, claim, options, cpu):
        return "recorded"
    with factory() as s, s.begin():  # handed back for another attempt: it needs a new message, sent once
        enqueue(app, work.take_unsent(s, stale_after_s=0, ids=[claim.episode_id]), countdown=RETRY_DELAY_S)
    return "dropped"


def _on_process_init(**_kw: Any) -> None:
    forget_inherited_engines()


def register(app: Celery) -> None:
    # shared=False: a shared task (Celery's default) is added to every app made later in the process, and the
    # first app's closure wins — a second app's episodes ran with the first app's options (its database).
    @app.task(name=TASK_NAME, ignore_result=True, shared=False)  # type: ignore[untyped-decorator]  # celery: no types
    def run_episode_task(episode_id: Any) -> str:
        return execute(app, parse_episode_id(episode_id))

    from celery.signals import worker_process_init

    worker_process_init.connect(_on_process_init, weak=False, dispatch_uid="robobpp-forget-engines")
