"""What a worker needs to know, as plain data (it crosses process boundaries and the server's settings
stay on the server side of the one-way imports: ``Settings.worker_options()`` builds it)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True, slots=True)
class WorkerOptions:
    database_url: str
    groups: int = 30
    private_dir: Path = Path("datasets_private")
    spec_provider: str = ""
    #: Short, renewed every quarter lease by a heartbeat: a dead worker's episode is re-sent within ~25 s.
    lease_s: float = 20.0
    max_attempts: int = 3
    poll_interval_s: float = 0.5
    step_timeout_s: float = 10.0
    episode_timeout_s: float = 1800.0
    response_cap_bytes: int = 64 * 1024
    #: Episodes of one participant's remote policies running at once (outbound calls to one server).
    max_running_per_participant: int = 4
