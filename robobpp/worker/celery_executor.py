"""The Celery executor: what the server runs instead of the local pool when ``ROBOBPP_BROKER_URL`` is set.

The server does not run episodes; it *dispatches* them. One background thread:

1. sends a message for every pending episode that has none out (new submissions, the baselines, episodes
   handed back for a retry), marking it in SQL (``enqueued_at``) in the same transaction: after a server
   restart nothing already queued is sent again, and nothing pending is forgotten;
2. sweeps expired leases: a running episode whose worker died (``kill -9``, a lost machine) is put back to
   ``pending`` and sent again, in one transaction, so exactly one sweeper re-sends it even when many run;
3. re-sends lost messages: a pending episode marked sent more than a delivery timeout ago while the queue is
   empty has no message left anywhere a live worker will take it from (lost by the broker, or reserved by
   a worker that died before claiming it, which Redis hides until its visibility timeout): it is sent
   again (:func:`resend_lost`).

Broker redelivery (acks late) is the fast path; the sweep is the path that always works, whatever the
broker does with an unacknowledged message (RabbitMQ requeues at once, Redis only after its visibility
timeout). ``robobpp worker`` runs the same sweep, so a fleet heals even while the server is down.
"""

from __future__ import annotations

import logging
import threading
import time
from datetime import datetime

from celery import Celery
from sqlalchemy import create_engine, update
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import NullPool

from robobpp.db import work
from robobpp.db.models import EpisodeRow, utcnow
from robobpp.db.session import make_engine, make_session_factory
from robobpp.worker.celery_names import options_of, queue_of
from robobpp.worker.options import WorkerSettings
from robobpp.worker.outage import OutageLog
from robobpp.worker.tasks import enqueue

log = logging.getLogger("robobpp.worker.celery")


def requeue_expired(
    session: Session, app: Celery, max_attempts: int, now: datetime | None = None
) -> list[int]:
    """Expired leases → ``pending`` + a new message each (the last allowed attempt → ``failed``).

    The send happens inside the caller's transaction: if the broker is down the rows stay ``running`` and
    the next sweep tries again; a commit that fails after a send leaves a duplicate message, which the
    claim turns into a no-op.
    """
    now = now or utcnow()
    work.reap_expired(session, max_attempts, now)
    ids = list(
        session.execute(
            update(EpisodeRow)
            .where(
                EpisodeRow.status == "running",
                EpisodeRow.lease_expires_at < now,
                EpisodeRow.attempts < max_attempts,
            )
            .values(status="pending", lease_token=None, lease_expires_at=None, enqueued_at=now)
            .returning(EpisodeRow.id)
            .execution_options(synchronize_session=False)
        ).scalars()
    )
    if ids:
        enqueue(app, ids)
        log.warning("re-sent %d episode(s) whose worker stopped renewing its lease: %s", len(ids), ids[:20])
    return ids


class _Loop(threading.Thread):
    """A daemon thread calling ``tick`` every ``interval`` seconds until stopped.

    ``tick`` returns the dependencies it used (``database``, ``broker``); outages of those are logged
    once when they start and once when they end (:class:`OutageLog`), not once per round.
    """

    def __init__(self, name: str, app: Celery, interval: float) -> None:
        super().__init__(name=name, daemon=True)
        self.app = app
        self.interval = interval
        self.stopping = threading.Event()
        self.outages = OutageLog(log, name)

    def tick(self) -> tuple[str, ...]:  # pragma: no cover - overridden
        raise NotImplementedError

    def run(self) -> None:
        while not self.stopping.is_set():
            try:
                used = self.tick()
                if "broker" in self.outages.down_since and "broker" not in used:
                    # A round that had nothing to send does not say whether the broker is back: ask it, so
                    # "reachable again" is logged when it is, not at the next send minutes later.
                    queue_length(self.app)
                    used = (*used, "broker")
                self.outages.ok(*used)
            except Exception as exc:  # noqa: BLE001 - the database or broker blinked: try again next round
                self.outages.failed(exc)
            self.stopping.wait(self.interval)

    def stop(self, timeout: float = 5.0) -> None:
        self.stopping.set()
        if self.is_alive():
            self.join(timeout)


def _own_factory(database_url: str) -> sessionmaker[Session]:
    # NullPool: no pooled socket can be inherited by a child forked while this thread is idle.
    if database_url.startswith("sqlite"):
        return make_session_factory(make_engine(database_url))
    return make_session_factory(create_engine(database_url, poolclass=NullPool))


class LeaseSweeper(_Loop):
    """The expired-lease sweep alone (runs in every ``robobpp worker``)."""

    def __init__(self, app: Celery, interval: float | None = None) -> None:
        options = options_of(app)
        super().__init__("robobpp-lease-sweeper", app, interval or sweep_interval_s(options.lease_s))
        self.options = options
        self.factory = _own_factory(options.database_url)

    def tick(self) -> tuple[str, ...]:
        with self.factory() as s, s.begin():
            sent = requeue_expired(s, self.app, self.options.max_attempts)
        sent += resend_lost(self.factory, self.app)
        return ("database", "broker") if sent else ("database",)


class CeleryExecutor(_Loop):
    """Server side of the scaled deployment: dispatch pending episodes, sweep leases, count workers.

    Same surface as :class:`robobpp.worker.local.LocalExecutor` (``start``, ``stop``, ``alive``). What has
    been sent is recorded in SQL (``episodes.enqueued_at``), not in memory, so a restarted server — or a
    second one — sends nothing that is already queued.
    """

    def __init__(self, app: Celery, *, ping_every_s: float = 15.0) -> None:
        options = options_of(app)
        super().__init__("robobpp-dispatcher", app, options.poll_interval_s)
        self.options = options
        self.factory = _own_factory(options.database_url)
        self._workers = 0
        self._ping_every_s = ping_every_s
        self._last_ping = 0.0
        self._last_sweep = 0.0

    def dispatch(self) -> int:
        """Send a message for every pending episode that has none out; the marks commit with the sends."""
        return dispatch_unsent(self.factory, self.app)

    def sweep(self) -> list[int]:
        with self.factory() as s, s.begin():
            return requeue_expired(s, self.app, self.options.max_attempts)

    def tick(self) -> tuple[str, ...]:
        now = time.monotonic()
        sent = 0
        if now - self._last_sweep >= sweep_interval_s(self.options.lease_s):
            self._last_sweep = now
            sent += len(self.sweep())
        sent += self.dispatch()
        sent += len(resend_lost(self.factory, self.app))
        if now - self._last_ping >= self._ping_every_s:
            self._last_ping = now
            self._workers = count_workers(self.app)
        return ("database", "broker") if sent else ("database",)

    def alive(self) -> int:
        """Celery workers that answered the last ping (health page; refreshed every ``ping_every_s``)."""
        return self._workers


def sweep_interval_s(lease_s: float) -> float:
    """How often leases are swept: a quarter lease, so a dead worker's episode is re-sent within 1.25 leases."""
    return max(1.0, lease_s / 4)


def dispatch_unsent(factory: sessionmaker[Session], app: Celery) -> int:
    from robobpp.worker.celery_app import visibility_timeout_s

    options = options_of(app)
    with factory() as s, s.begin():
        ids = work.take_unsent(
            s, stale_after_s=visibility_timeout_s(options.episode_timeout_s, options.lease_s)
        )
        enqueue(app, ids)
    return len(ids)


def delivery_timeout_s(lease_s: float) -> float:
    """How long a message may stay out, with the queue empty and its episode unclaimed, before it is presumed
    lost: one lease, at least 10 s (a worker that reserved it claims it within milliseconds)."""
    return max(10.0, float(lease_s))


def queue_length(app: Celery) -> int:
    """Messages waiting in the episode queue (ready ones: not those reserved by a worker). A queue that does
    not exist holds none (Redis drops an empty list).

    A fresh connection per call, never one from the app's pool: after a broker outage kombu hands a pooled
    connection back *closed* (its transport connection ``None``), and every later ``channel()`` on it fails
    with ``AttributeError: 'NoneType' object has no attribute '_used_channel_ids'`` (Redis) or ``... 'channel'``
    (RabbitMQ) — for as long as nothing else happens to reconnect it, which is exactly when lost messages
    wait to be re-sent. One connection per check costs a TCP handshake, once per poll at most.
    """
    with app.connection_for_read() as conn:
        conn.ensure_connection(max_retries=1)
        try:
            with conn.channel() as channel:
                return int(channel.queue_declare(queue=queue_of(app), passive=True).message_count)
        except conn.channel_errors:
            return 0


def declare_queue(app: Celery) -> None:
    """Declare the episode queue as the workers do (nothing changes when it exists), on a fresh connection
    (:func:`queue_length` says why).

    A broker that lost the queue itself (a RabbitMQ restart without persistence, or a deleted queue) drops
    every message published to it until a worker reconnects and declares it again: the default exchange
    routes by queue name, and an unroutable message vanishes without an error. The app's producer does not
    declare it again, for it remembers having declared it once. Redis makes the list on the first push, so
    this is only a round trip there. Called before lost messages are re-sent, so that the copies reach a queue
    whether or not a worker is back yet.
    """
    queue = app.amqp.queues[queue_of(app)]
    with app.connection_for_write() as conn:
        conn.ensure_connection(max_retries=1)
        with conn.channel() as channel:
            queue.bind(channel).declare()


def resend_lost(factory: sessionmaker[Session], app: Celery) -> list[int]:
    """Send again the pending episodes whose message is neither queued nor with a live worker.

    The mark (``enqueued_at``) says a message was sent, not that a worker can still get it: a broker can
    lose it (a Redis restart without persistence), and a worker killed after reserving it but before its
    claim takes it along; Redis hands such a message out again only after its visibility timeout, an hour
    with the defaults, while RabbitMQ requeues it at once. A message that still waits in the queue is not
    lost, however old (a backlog). So: when a pending episode was marked sent more than
    :func:`delivery_timeout_s` ago *and the queue is empty*, its message is gone; it is sent again. With a
    backlog nothing is re-sent until the queue drains, so a backlog never multiplies messages; a copy that
    turns out not to be lost is a duplicate, which the claim turns into a no-op. The conditional UPDATE of
    :func:`work.take_unsent` makes concurrent checkers (server replicas, worker sweepers) send it once.
    """
    options = options_of(app)
    timeout = delivery_timeout_s(options.lease_s)
    with factory() as s, s.begin():
        if not work.has_overdue(s, older_than_s=timeout):
            return []
        # Asked after the database: a message sent since is fresh, so it can only make the queue longer.
        if queue_length(app):
            return []
        ids = work.take_unsent(s, stale_after_s=timeout)
        if ids:
            declare_queue(app)
        enqueue(app, ids)
    if ids:
        log.warning(
            "re-sent %d episode(s) whose message was neither queued nor claimed after %.0f s: %s",
            len(ids),
            timeout,
            ids[:20],
        )
    return ids


def count_workers(app: Celery, timeout: float = 1.0) -> int:
    try:
        replies = app.control.ping(timeout=timeout) or []
    except Exception:  # noqa: BLE001 - an unreachable broker means no reachable workers
        return 0
    return len(replies)


def executor_from_settings(settings: WorkerSettings) -> CeleryExecutor:
    """The server's hook: ``Settings`` with a broker URL → a started-on-demand executor."""
    from robobpp.worker.celery_app import app_from_settings

    return CeleryExecutor(app_from_settings(settings))


__all__ = [
    "CeleryExecutor",
    "LeaseSweeper",
    "declare_queue",
    "delivery_timeout_s",
    "dispatch_unsent",
    "executor_from_settings",
    "queue_length",
    "requeue_expired",
    "resend_lost",
]
