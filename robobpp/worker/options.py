"""What a worker needs to know, declared once: the server's settings inherit these fields, a worker's options
are taken from them.

:class:`WorkerSettings` holds every setting a worker reads, with its default and bounds; the server's
:class:`robobpp.server.config.Settings` inherits it (and reads it from the same ``ROBOBPP_*`` variables), so a
default changed here changes for both. :class:`WorkerOptions` is what one worker runs with, as plain frozen
data that crosses process boundaries (a spawned pool process, a Celery app's configuration), made by
:func:`worker_options`. This module imports nothing of robobpp: the server's settings read it without
pulling in worker code.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field


class EvaluationOptions(BaseModel):
    """How episodes are evaluated: the settings a worker runs every episode with."""

    #: Evaluation groups per dataset (30 on the real leaderboard, fewer for the demo).
    groups: int = Field(default=30, ge=1, le=1000)
    #: Where the private split lives (built on first start if absent).
    private_dir: Path = Path("datasets_private")
    #: ``module:function(dataset, split, group, groups) -> EpisodeSpec`` override (tests, offline demo).
    spec_provider: str = ""
    #: Boxes of each episode played at most: the first ones of its group (0: every box, as the benchmark).
    #: The demo plays a few so that its boards fill within minutes; never on a real leaderboard.
    max_boxes: int = Field(default=0, ge=0)
    #: Worker lease; renewed every quarter lease (heartbeat), swept every quarter lease: a dead worker's
    #: episode is back in the queue within 1.25 leases (25 s with the default).
    lease_s: float = Field(default=20.0, gt=0)
    #: Episodes of one participant's remote policies running at once, whatever the number of workers. One by
    #: default: a policy server is then never asked two decisions at once, so its Decision Time is its own (a
    #: server that answers one request at a time, as the SDK's, would count the wait for another episode's
    #: decision as thinking, and its network probes would queue behind it; docs/protocol.md, "Decision time and
    #: the network").
    participant_max_running: int = Field(default=1, ge=1, le=1000)
    max_attempts: int = Field(default=3, ge=1, le=20)
    poll_interval_s: float = Field(default=0.5, gt=0)
    step_timeout_s: float = Field(default=10.0, gt=0)
    episode_timeout_s: float = Field(default=1800.0, gt=0)
    response_cap_bytes: int = Field(default=64 * 1024, ge=1024)
    # pull mode (robobpp connect): workers reach the participants' clients through this server's relay
    #: The server's URL as the workers see it; ``robobpp serve`` fills in its own address when empty.
    pull_relay_url: str = ""
    #: How long a worker waits for a participant's client before handing the episode back for a retry.
    pull_wait_s: float = Field(default=30.0, gt=0)
    #: How long a worker waits for a dropped client to come back before the episode ends with policy_error.
    pull_reconnect_s: float = Field(default=30.0, gt=0)
    #: Episodes one worker process keeps in flight: a further one is claimed only while every episode in flight
    #: waits on its participant's policy (docs/server.md, "Evaluation"); 1: one episode at a time.
    episodes_per_worker: int = Field(default=16, ge=1, le=256)


class WorkerSettings(EvaluationOptions):
    """Every setting a worker reads: how episodes are evaluated, where the database is, and the broker."""

    #: SQLAlchemy URL; empty means a SQLite file inside ``state_dir``.
    database_url: str = ""
    state_dir: Path = Path("robobpp-data")
    #: Celery executor (scaled deployment): ``redis://…`` or ``amqp://…``; empty = local process pool.
    broker_url: str = ""
    #: Broker queue the episode tasks go to (one per deployment; tests use a fresh one per run).
    celery_queue: str = "robobpp-episodes"

    @property
    def sqlalchemy_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.state_dir / 'robobpp.sqlite3').resolve()}"


class WorkerOptions(EvaluationOptions):
    """What one worker runs with (frozen: it is shared by the worker's threads and copied to its processes)."""

    model_config = ConfigDict(frozen=True)

    #: The SQLAlchemy URL of the work queue.
    database_url: str


def worker_options(settings: WorkerSettings) -> WorkerOptions:
    """The options of a worker running under ``settings`` (the server's, or a worker's own)."""
    evaluation = {name: getattr(settings, name) for name in EvaluationOptions.model_fields}
    return WorkerOptions(database_url=settings.sqlalchemy_url, **evaluation)


__all__ = ["EvaluationOptions", "WorkerOptions", "WorkerSettings", "worker_options"]
