"""The Celery application of the scaled deployment (``ROBOBPP_BROKER_URL`` = ``redis://…`` or ``amqp://…``).

Why Celery is configured the way it is — each line below protects one property of the evaluation:

- **acks late + reject on worker lost**: a message is acknowledged only after its episode has been
  written to SQL, so a worker killed mid-episode leaves the message with the broker (RabbitMQ requeues it
  when the connection drops; Redis restores it after the visibility timeout).
- **prefetch 1**: an episode lasts seconds to minutes; a worker that reserved a second one would hold it
  hostage while a sibling idles.
- **JSON only**: the broker is a shared network service; pickle would let anyone who can write to it run
  code in the workers. The only payload is an episode row id.
- **visibility timeout longer than the longest episode** (Redis): otherwise Redis would hand a running
  episode to a second worker. It is derived from ``episode_timeout_s`` so the two cannot drift apart.
- **task id = episode id**: the broker, the logs and the SQL row name the work alike; redelivered or
  re-enqueued copies of one episode are the same task, and the SQL lease (not the broker) decides which
  copy may write. SQL stays the record of truth; no result backend is used.
"""

from __future__ import annotations

from typing import Any

from celery import Celery

from robobpp.worker import tasks
from robobpp.worker.celery_names import (
    DEFAULT_QUEUE,
    TASK_ID_PREFIX,
    TASK_NAME,
    options_of,
    queue_of,
    task_id,
)
from robobpp.worker.options import WorkerOptions, WorkerSettings, worker_options

SUPPORTED_SCHEMES = ("redis", "rediss", "amqp", "amqps", "pyamqp")


class BrokerURLError(ValueError):
    """The broker URL is not one the scaled deployment supports."""


def check_broker_url(url: str) -> str:
    """Refuse anything but Redis or RabbitMQ, with a message that names what was given."""
    scheme = url.split("://", 1)[0].lower() if "://" in url else ""
    if scheme not in SUPPORTED_SCHEMES:
        shown = url.split("@")[-1] if "@" in url else url  # never echo credentials
        raise BrokerURLError(
            f"ROBOBPP_BROKER_URL must be redis://… or amqp://… (got {shown!r}); "
            "leave it empty to use the local process-pool executor"
        )
    return url


def visibility_timeout_s(episode_timeout_s: float, lease_s: float) -> int:
    """Twice the longest episode plus one lease: a running episode is never handed out again by Redis."""
    return int(2 * episode_timeout_s + lease_s + 60)


def celery_config(broker_url: str, *, queue: str, episode_timeout_s: float, lease_s: float) -> dict[str, Any]:
    """The Celery settings as a plain dict (tests read it; ``make_celery`` applies it)."""
    check_broker_url(broker_url)
    return {
        "broker_url": broker_url,
        "broker_connection_retry_on_startup": True,
        "broker_transport_options": {
            "visibility_timeout": visibility_timeout_s(episode_timeout_s, lease_s),
            # Redis: keep the unacked index per queue so two deployments on one Redis do not mix.
            "unacked_key": f"unacked:{queue}",
            "unacked_index_key": f"unacked_index:{queue}",
            "unacked_mutex_key": f"unacked_mutex:{queue}",
        },
        "task_default_queue": queue,
        "task_routes": {TASK_NAME: {"queue": queue}},
        "task_serializer": "json",
        "accept_content": ["json"],
        "result_serializer": "json",
        "result_accept_content": ["json"],
        "task_ignore_result": True,
        "result_backend": None,
        "task_acks_late": True,
        "task_reject_on_worker_lost": True,
        "task_acks_on_failure_or_timeout": True,
        "worker_prefetch_multiplier": 1,
        "worker_max_tasks_per_child": 200,  # bounds any slow leak in the simulators
        "worker_hijack_root_logger": False,
        "worker_send_task_events": False,
        "task_send_sent_event": False,
        # Episodes enforce their own time budget; this is the backstop for a wedged simulator.
        "task_time_limit": int(episode_timeout_s + lease_s + 60),
        "enable_utc": True,
        "timezone": "UTC",
    }


def make_celery(
    broker_url: str,
    options: WorkerOptions,
    *,
    queue: str = DEFAULT_QUEUE,
) -> Celery:
    """The app: broker settings above, the episode task, and the worker options the task runs with.

    The options travel inside the app object (prefork children inherit it), so a task never reads the
    server's settings: the one-way imports (worker ← server) hold and a worker needs only its environment.
    """
    app = Celery("robobpp", set_as_current=False)
    app.conf.update(
        celery_config(
            broker_url, queue=queue, episode_timeout_s=options.episode_timeout_s, lease_s=options.lease_s
        )
    )
    app.conf.robobpp_options = options
    app.conf.robobpp_queue = queue
    tasks.register(app)
    return app


def app_from_settings(settings: WorkerSettings) -> Celery:
    """The app for a worker's settings (the server's :class:`robobpp.server.config.Settings` are some): its
    broker, queue and options."""
    if not settings.broker_url:
        raise BrokerURLError("ROBOBPP_BROKER_URL is empty: the Celery executor needs a broker")
    return make_celery(
        settings.broker_url, worker_options(settings), queue=settings.celery_queue or DEFAULT_QUEUE
    )


__all__ = [
    "DEFAULT_QUEUE",
    "SUPPORTED_SCHEMES",
    "TASK_ID_PREFIX",
    "TASK_NAME",
    "BrokerURLError",
    "app_from_settings",
    "celery_config",
    "check_broker_url",
    "make_celery",
    "options_of",
    "queue_of",
    "task_id",
    "visibility_timeout_s",
]
