"""Server settings: one pydantic-settings object, read from ``ROBOBPP_*`` environment variables.

This module imports only the vocabulary and the worker's settings (:class:`robobpp.worker.options.WorkerSettings`,
which it inherits: what a worker reads is declared there, once): ``robobpp worker`` reads it too, and a
worker must not pull in the server, nor the server's settings the rest of the worker
(``robobpp.worker.options.worker_options`` turns them into the worker's plain options).

Why one object: every part of the service (API, workers, CLI) sees the same configuration, and the one
place that refuses unsafe defaults (a missing or weak admin token outside dev) cannot be bypassed.
"""

from __future__ import annotations

import os
import secrets
from functools import cached_property
from typing import Literal

from pydantic import Field, SecretStr, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from robobpp.vocabulary import DATASETS
from robobpp.worker.options import WorkerSettings

#: URL schemes of the brokers the pull relay's bus speaks (server/relay_bus.py, server/relay_amqp.py).
BUS_SCHEMES = ("redis://", "rediss://", "unix://", "amqp://", "amqps://", "pyamqp://")

#: Admin tokens that must never guard a real deployment.
WEAK_TOKENS = frozenset({"", "changeme", "change-me", "admin", "secret", "password", "token"})


class InsecureSettingsError(ValueError):
    """The settings would run a non-dev server with a default or weak secret."""


class Settings(BaseSettings, WorkerSettings):
    """Everything the server, its workers and its CLI read from the environment (what a worker reads:
    :class:`~robobpp.worker.options.WorkerSettings`, inherited)."""

    model_config = SettingsConfigDict(env_prefix="ROBOBPP_", extra="ignore", validate_default=True)

    #: ``dev`` allows a generated admin token; ``prod`` demands a strong one from the environment.
    env: Literal["dev", "prod"] = "dev"
    admin_token: SecretStr | None = None
    #: Policy URLs may point at private/loopback/link-local addresses (local dev, tests, the demo).
    allow_private_policy_urls: bool = False
    #: Built-in participants' policies (``builtin:<name>``) may be submitted by the admin only.
    demo: bool = False

    #: Base URL of the project's documentation files (a repository's tree, ending in ``/``): the Reproduction
    #: page links its docs references (``docs/physics.md#…``) under it; empty: it shows them as paths.
    docs_url: str = ""

    # evaluation
    workers: int = Field(default=2, ge=0, le=64)
    datasets: tuple[str, ...] = DATASETS
    #: Settings a submission may ask for; physics/execution join when their modules import.
    settings: tuple[str, ...] = ()
    #: Broker the API processes' pull relays meet through (``redis://…`` or ``amqp://…``); empty: ``broker_url``,
    #: else the relay lives in the one API process (docs/deploy.md, "Several API processes").
    pull_broker_url: str = ""
    evaluate_baselines: bool = True
    #: Built-in baselines evaluated on first start; ``None`` means every one (``robobpp.policies.BASELINES``).
    baselines: tuple[str, ...] | None = None
    #: Also evaluate the baselines on the public track, so a debug run there is compared with something.
    public_baselines: bool = True
    #: How often (seconds) an API process checks in SQL whether a board was published (boards/reader.py).
    board_refresh_s: float = Field(default=1.0, ge=0, le=60)
    #: How long a reader waits for the board worker when the boards are behind the data and their last
    #: publication took no longer than this; a slower board is served as it was until its successor lands.
    board_wait_s: float = Field(default=2.0, ge=0, le=60)
    #: Where the board worker runs (boards/worker.py): ``process`` (spawned beside the API process),
    #: ``thread`` (inside it) or ``off`` (another process or host of the deployment runs it).
    board_worker: Literal["process", "thread", "off"] = "process"
    #: How often (seconds) the board worker checks whether a track's data changed.
    board_poll_s: float = Field(default=0.5, gt=0, le=60)
    #: How often (seconds) the board worker recomputes each track in full: an update after a submission
    #: finishes recomputes the all-entries rank intervals only then (boards/engine.py).
    board_full_s: float = Field(default=300.0, gt=0)
    #: The API process's GIL switch interval (``sys.setswitchinterval``): how long a worker thread back from
    #: SQL may wait for the event loop to hand over the interpreter.
    switch_interval_s: float = Field(default=0.0005, gt=0, le=0.1)
    #: Worker threads of the API process for routes that read or write SQL (0: the framework's 40).
    api_threads: int = Field(default=0, ge=0, le=256)

    # API limits
    max_body_bytes: int = Field(default=64 * 1024, ge=1024)
    #: Submit-time ``GET /info`` checks: deadline on the whole exchange, at most this many at once overall
    #: and per participant (server/probes.py).
    probe_timeout_s: float = Field(default=5.0, gt=0, le=60)
    probe_concurrency: int = Field(default=8, ge=1, le=256)
    probe_per_participant: int = Field(default=1, ge=1, le=64)
    quota_submissions_per_day: int = Field(default=10, ge=0)
    quota_concurrent: int = Field(default=2, ge=0)
    #: Wrong tokens (API, sign-in, pull) per minute from one client address, with one token prefix, or for one
    #: participant's prefixes, before further ones are refused (429; server/ratelimit.py).
    auth_failures_per_minute: int = Field(default=10, ge=1, le=100_000)
    #: Peers whose ``X-Forwarded-For`` / ``X-Forwarded-Proto`` are believed (the reverse proxy's addresses,
    #: comma-separated; networks such as ``172.18.0.0/16`` too): uvicorn's ``forwarded_allow_ips``. From any
    #: other peer the headers are ignored, so a client cannot pick the address its wrong tokens count against.
    #: Unset: uvicorn's own ``FORWARDED_ALLOW_IPS`` if set, else ``127.0.0.1``. ``*`` is refused outside dev.
    trusted_proxies: str = ""
    #: ``/metrics`` without the admin token (e.g. a Prometheus on a private network that cannot send one).
    metrics_public: bool = False
    # connection limits (server/connections.py; docs/deploy.md, "Reverse proxy and limits")
    #: Open connections of the API process (HTTP and WebSocket); over it a new one is answered 503 and closed.
    max_connections: int = Field(default=1000, ge=1)
    #: Open connections from one client address (0: none; behind a reverse proxy, let the proxy limit them).
    max_connections_per_client: int = Field(default=160, ge=0)
    #: A request's headers must be complete this long after its connection opened or its previous response.
    header_timeout_s: float = Field(default=10.0, gt=0, le=600)
    #: A request's body must be complete this long after its headers (else 408).
    body_timeout_s: float = Field(default=30.0, gt=0, le=3600)
    #: Pull-mode client connections (robobpp connect) open at once per submission and per participant.
    pull_max_per_submission: int = Field(default=64, ge=1, le=10_000)
    pull_max_per_participant: int = Field(default=128, ge=1, le=10_000)

    @model_validator(mode="after")
    def _refuse_weak_secrets(self) -> Settings:
        token = self.admin_token.get_secret_value() if self.admin_token else None
        if self.env != "dev":
            if token is None or token.lower() in WEAK_TOKENS or len(token) < 16:
                raise InsecureSettingsError(
                    "ROBOBPP_ADMIN_TOKEN must be set to a random string of at least 16 characters "
                    "when ROBOBPP_ENV is not 'dev'"
                )
            if self.allow_private_policy_urls:
                raise InsecureSettingsError("ROBOBPP_ALLOW_PRIVATE_POLICY_URLS is for dev only")
            if "*" in self.forwarded_allow_ips.replace(" ", "").split(","):
                raise InsecureSettingsError(
                    "trusting X-Forwarded-For from every peer ('*') lets any client choose the address its "
                    "wrong tokens count against: set ROBOBPP_TRUSTED_PROXIES to the reverse proxy's "
                    "address(es) (docs/deploy.md, 'Reverse proxy and limits')"
                )
        return self

    @property
    def forwarded_allow_ips(self) -> str:
        """The peers uvicorn takes ``X-Forwarded-*`` from: ``trusted_proxies``, else uvicorn's own variable."""
        return self.trusted_proxies or os.environ.get("FORWARDED_ALLOW_IPS", "") or "127.0.0.1"

    @cached_property
    def effective_admin_token(self) -> str:
        """The admin token: from the environment, or (dev only) a random one stored in the data dir."""
        if self.admin_token is not None:
            return self.admin_token.get_secret_value()
        path = self.state_dir / "admin_token"
        if path.exists():
            return path.read_text().strip()
        self.state_dir.mkdir(parents=True, exist_ok=True)
        token = secrets.token_urlsafe(32)
        path.write_text(token + "\n")
        path.chmod(0o600)
        return token

    @property
    def worker_slots(self) -> int:
        """Episodes this server's own pool runs at once (its local workers); 0 with Celery, whose workers run
        elsewhere in numbers the server does not know."""
        return 0 if self.broker_url else self.workers

    @property
    def pull_bus_url(self) -> str:
        """The broker of the pull relay's bus (Redis or RabbitMQ), or ``""`` for the in-process relay (one API
        process only): ``pull_broker_url``, else the Celery broker."""
        return self.pull_broker_url or self.broker_url

    @model_validator(mode="after")
    def _pull_broker_is_known(self) -> Settings:
        if self.pull_broker_url and not self.pull_broker_url.startswith(BUS_SCHEMES):
            raise ValueError(
                "ROBOBPP_PULL_BROKER_URL must be a Redis or RabbitMQ URL (redis://host:port/db, "
                f"amqp://user:password@host:port/vhost), got {self.pull_broker_url!r}"
            )
        return self

    @cached_property
    def enabled_settings(self) -> tuple[str, ...]:
        """The settings submissions may use: configured, or every one whose simulator imports."""
        if self.settings:
            return self.settings
        found = ["math"]
        for name, module in (("physics", "robobpp.sim.physics"), ("execution", "robobpp.sim.execution")):
            try:
                __import__(module)
            except Exception:  # noqa: BLE001 - a setting that cannot load is simply not offered
                continue
            found.append(name)
        return tuple(found)


def get_settings() -> Settings:
    return Settings()
