"""What a worker needs to know, as plain data (it crosses process boundaries and the server's settings
stay on the server side of the one-way imports: :func:`worker_options` reads them duck-typed)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True, slots=True)
class WorkerOptions:
    database_url: str
    groups: int = 30
    private_dir: Path = Path("datasets_private")
    spec_provider: str = ""
    #: Boxes of each episode played at most (0: every box): the demo's short episodes.
    max_boxes: int = 0
    #: Short, renewed every quarter lease by a heartbeat: a dead worker's episode is re-sent within ~25 s.
    lease_s: float = 20.0
    max_attempts: int = 3
    poll_interval_s: float = 0.5
    step_timeout_s: float = 10.0
    episode_timeout_s: float = 1800.0
    response_cap_bytes: int = 64 * 1024
    pull_relay_url: str = ""
    pull_wait_s: float = 30.0
    pull_reconnect_s: float = 30.0
    #: Episodes of one participant's remote policies running at once (outbound calls to one server).
    max_running_per_participant: int = 1
    #: Episodes one worker process keeps in flight (robobpp/worker/multiplex.py); 1: one at a time.
    episodes_per_worker: int = 16


def worker_options(settings: Any) -> WorkerOptions:
    """The options of a :class:`robobpp.server.config.Settings` (duck-typed: no import of the server)."""
    return WorkerOptions(
        database_url=settings.sqlalchemy_url,
        groups=settings.groups,
        private_dir=settings.private_dir,
        spec_provider=settings.spec_provider,
        max_boxes=settings.max_boxes,
        lease_s=settings.lease_s,
        max_attempts=settings.max_attempts,
        poll_interval_s=settings.poll_interval_s,
        step_timeout_s=settings.step_timeout_s,
        episode_timeout_s=settings.episode_timeout_s,
        response_cap_bytes=settings.response_cap_bytes,
        pull_relay_url=settings.pull_relay_url,
        pull_wait_s=settings.pull_wait_s,
        pull_reconnect_s=settings.pull_reconnect_s,
        max_running_per_participant=settings.participant_max_running,
        episodes_per_worker=settings.episodes_per_worker,
    )
