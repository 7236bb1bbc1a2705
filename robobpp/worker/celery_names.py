"""Names shared by the Celery app and its task module: the task's name, the queue, the task id.

They sit in a leaf module so that ``celery_app`` (which builds the app and registers the task) and
``tasks`` (which the app registers) import in one direction only.
"""

from __future__ import annotations

from typing import Any

from robobpp.worker.options import WorkerOptions

#: Queue the episodes go to unless ``ROBOBPP_CELERY_QUEUE`` says otherwise (tests use one per run).
DEFAULT_QUEUE = "robobpp-episodes"
#: Name under which workers know the episode task (stable: it is written into broker messages).
TASK_NAME = "robobpp.run_episode"
#: Prefix of the Celery task id; the rest is the episode row id, so ids stay unique per database row.
TASK_ID_PREFIX = "episode-"


def task_id(episode_id: int | str) -> str:
    return f"{TASK_ID_PREFIX}{int(episode_id)}"


def options_of(app: Any) -> WorkerOptions:
    """The worker options an app built by ``make_celery`` carries."""
    options = app.conf.get("robobpp_options")
    if not isinstance(options, WorkerOptions):
        raise RuntimeError("this Celery app was not built by robobpp.worker.celery_app.make_celery")
    return options


def queue_of(app: Any) -> str:
    return str(app.conf.get("robobpp_queue") or DEFAULT_QUEUE)
