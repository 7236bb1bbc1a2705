"""``robobpp worker``: a Celery worker of the scaled deployment, on any machine that reaches the broker
and the database.

It reads the same ``ROBOBPP_*`` settings as the server (database, broker, queue, lease, timeouts), runs
``--concurrency`` worker processes, each keeping up to ``ROBOBPP_EPISODES_PER_WORKER`` episodes in flight as a
local worker does (robobpp/worker/multiplex.py, robobpp/worker/nodes.py), and sweeps expired leases so that
episodes of a dead worker are sent again even while the server is down.
"""

from __future__ import annotations

import os
import secrets
import socket
from typing import TYPE_CHECKING, Annotated, Any

import typer

from robobpp.cli.common import fail, settings_problem

if TYPE_CHECKING:  # imported when a worker starts (pydantic-settings is the server extra's)
    from robobpp.server.config import Settings

POOLS = ("multiplex", "prefork", "solo", "threads")


def register(root: typer.Typer) -> None:
    root.command("worker")(worker)


def worker_settings() -> Settings:
    """The settings a worker runs with: the server's, from the same environment variables.

    A worker serves no API and never reads the admin token, so a worker machine need not hold it: when
    ``ROBOBPP_ADMIN_TOKEN`` is absent a throwaway random one satisfies the production check (every other
    check, e.g. no private policy URLs in production, still applies).
    """
    from robobpp.server.config import Settings

    overrides: dict[str, Any] = {}
    if not os.environ.get("ROBOBPP_ADMIN_TOKEN"):
        overrides["admin_token"] = secrets.token_urlsafe(32)
    return Settings(**overrides)


def worker(
    concurrency: Annotated[
        int,
        typer.Option(
            "--concurrency",
            "-c",
            min=1,
            max=256,
            help="Worker processes (multiplex, prefork) or threads (threads). With multiplex each process keeps "
            "up to ROBOBPP_EPISODES_PER_WORKER episodes in flight.",
        ),
    ] = 2,
    pool: Annotated[
        str,
        typer.Option(
            help="multiplex (default: a Celery node per process, episodes in flight while they wait on their "
            "policies), prefork (one episode per process), solo (in-process) or threads."
        ),
    ] = "multiplex",
    loglevel: Annotated[str, typer.Option(help="debug, info, warning or error.")] = "info",
    hostname: Annotated[
        str | None,
        typer.Option(
            help="Celery node name; default robobpp-PID@HOST (unique per process); NAME-i@HOST per process."
        ),
    ] = None,
    parent_pid: Annotated[
        int | None, typer.Option(hidden=True, help="A node of `robobpp worker -c N`: end with that process.")
    ] = None,
) -> None:
    """Run episodes from the broker queue (needs ROBOBPP_BROKER_URL and ROBOBPP_DATABASE_URL)."""
    from pydantic import ValidationError

    from robobpp.extras import require

    for package in ("celery", "sqlalchemy", "pydantic_settings"):
        require(package, "worker", "robobpp worker")
    from robobpp.worker.celery_app import BrokerURLError, app_from_settings, check_broker_url

    if pool not in POOLS:
        fail(f"unknown pool {pool!r}; expected one of {', '.join(POOLS)}")
    if loglevel.lower() not in ("debug", "info", "warning", "error"):
        fail(f"unknown log level {loglevel!r}")
    try:
        settings = worker_settings()
    except (ValidationError, ValueError) as exc:
        fail(f"invalid settings: {settings_problem(exc)}")
    if not settings.broker_url:
        fail(
            "ROBOBPP_BROKER_URL is not set; `robobpp worker` serves the Celery executor (redis:// or amqp://)"
        )
    if not settings.database_url:
        fail("ROBOBPP_DATABASE_URL is not set; workers on a shared broker need the shared database")
    try:
        check_broker_url(settings.broker_url)
        app = app_from_settings(settings)
    except BrokerURLError as exc:
        fail(str(exc))
    if pool == "solo" and concurrency != 1:
        fail("--pool solo runs one episode at a time; use --concurrency 1 or the prefork pool")
    if parent_pid is not None:  # first thing after the checks: a node never outlives its supervisor
        from robobpp.worker.lifeline import Lifeline

        Lifeline(parent_pid, kernel=True).hold("worker node")
    if pool == "multiplex" and concurrency > 1:
        from robobpp.worker.nodes import NodeSupervisor, node_command, node_hostname

        me = os.getpid()
        supervisor = NodeSupervisor(
            concurrency,
            lambda i: node_command(loglevel=loglevel, hostname=node_hostname(hostname, i), parent_pid=me),
        )
        raise typer.Exit(supervisor.run())
    if pool == "multiplex":  # one process: a node whose threads are its episodes in flight
        pool, concurrency = "threads", settings.episodes_per_worker
    _run(
        app,
        concurrency=concurrency,
        pool=pool,
        loglevel=loglevel.upper(),
        hostname=hostname or f"robobpp-{os.getpid()}@{socket.gethostname()}",
    )


def _run(app: Any, *, concurrency: int, pool: str, loglevel: str, hostname: str) -> None:
    from celery.signals import worker_ready, worker_shutdown

    from robobpp.worker.celery_app import queue_of
    from robobpp.worker.celery_executor import LeaseSweeper

    sweeper = LeaseSweeper(app)

    # Started once the pool has forked its children, so no child inherits the sweeper's thread.
    def _start(**_kw: Any) -> None:
        sweeper.start()

    def _stop(**_kw: Any) -> None:
        sweeper.stop()

    worker_ready.connect(_start, weak=False)
    worker_shutdown.connect(_stop, weak=False)
    node = app.Worker(
        concurrency=concurrency,
        pool_cls=pool,
        loglevel=loglevel,
        hostname=hostname,
        queues=[queue_of(app)],
        without_gossip=True,
        without_mingle=True,
    )
    node.start()
    raise typer.Exit(node.exitcode or 0)
