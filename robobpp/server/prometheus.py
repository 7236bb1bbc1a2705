"""Prometheus ``/metrics``: request counts and latencies, plus the evaluation queue read from SQL.

Each app has its own registries so several apps (tests) never clash over global collectors.

The request counters and latency histograms (a dozen lines per route, hundreds in all) cost milliseconds of
CPU to render with ``prometheus_client``; they are rendered at most once per ``REQUEST_METRICS_MAX_AGE_S``
and served from that rendering meanwhile (a route seen for the first time renders them again at once). A
scraper polling every 15 s never sees the cache; a flood of scrapes no longer costs a rendering each. The
queue and board gauges are read at every scrape.

With several API processes (``robobpp serve --server-workers N``) a scrape reaches one of them, so the request
metrics are those of every process, summed: the supervisor gives its API processes a fresh
``PROMETHEUS_MULTIPROC_DIR`` (server/processes.py), each writes its counts there (``prometheus_client``'s
multiprocess mode) and a scrape renders the directory. The queue gauges come from SQL and are the same from any
process; the board gauges are the answering process's own.
"""

from __future__ import annotations

import hmac
import os
import threading
import time
from collections.abc import Iterable, Mapping
from typing import Any

import prometheus_client
from fastapi import FastAPI, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from robobpp.server.state import state_of

FINISHED_SUBMISSIONS = ("completed", "failed", "cancelled")
#: Request latency buckets (s): the 100 ms page target is one of the edges.
LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)
REQUEST_METRICS_MAX_AGE_S = 1.0


class _QueueCollector(Collector):
    """The queue (episodes pending or running) and submissions by status, read from SQL (the record of
    truth) at scrape time with a cost that does not grow with history: episodes and submissions queued or
    running are counted on their status indexes (their cost follows the queue); finished episodes are not
    counted (``queries.QUEUE_STATUSES``); finished submissions by status are recounted only when a
    submission finished since the last scrape (``queries.last_finished``, one index lookup per track)."""

    def __init__(self, app: FastAPI) -> None:
        self.app = app
        self._finished: tuple[tuple[Any, ...], dict[str, int]] | None = None

    def collect(self) -> Iterable[GaugeMetricFamily]:
        from robobpp.db import queries

        episodes = GaugeMetricFamily(
            "robobpp_episodes",
            "Episodes queued (waiting for their Math episode, pending) or running",
            labels=["status"],
        )
        submissions = GaugeMetricFamily("robobpp_submissions", "Submissions by status", labels=["status"])
        version = GaugeMetricFamily(
            "robobpp_board_version", "Publications of the track's boards so far", labels=["track"]
        )
        seconds = GaugeMetricFamily(
            "robobpp_board_publication_seconds",
            "Wall time of the track's last board computation and publication",
            labels=["track"],
        )
        try:
            with state_of(self.app).runtime.read_session() as session:  # one transaction for the whole scrape
                queue, active, marker = queries.queue_snapshot(session)  # one round trip
                if self._finished is None or self._finished[0] != marker:
                    finished = queries.submission_status_counts(session, FINISHED_SUBMISSIONS)
                    self._finished = (marker, finished)
                published = self._boards(session)
            for status, n in queue.items():
                episodes.add_metric([status], n)
            for status, n in {**active, **self._finished[1]}.items():
                submissions.add_metric([status], n)
            for track, at, took in published:
                version.add_metric([track], at)
                seconds.add_metric([track], took)
        except Exception:  # noqa: BLE001 - a scrape must not fail because the database blinked
            pass
        yield from (episodes, submissions, version, seconds)

    @staticmethod
    def _boards(session: Any) -> list[tuple[str, int, float]]:
        """Each track's published boards (boards/worker.py), whichever process computed them."""
        from sqlalchemy import select

        from robobpp.db.models import BoardPublication
        from robobpp.vocabulary import BOARD_TRACKS

        return [
            (track, published, took)
            for track, published, took in session.execute(
                select(BoardPublication.track, BoardPublication.version, BoardPublication.seconds).where(
                    BoardPublication.track.in_(BOARD_TRACKS)  # by primary key, as every scrape query
                )
            ).all()
        ]


def route_template(scope: Mapping[str, Any]) -> str:
    """The matched route's full path template (``/api/v1/submissions/{submission_id}``), or ``unmatched``.

    The template, not the URL, keeps the label set small whatever ids clients send. Recent FastAPI keeps
    included routers lazily: ``scope["route"]`` is then the route as declared in its router, *without*
    the ``/api/v1`` prefix, and the full template lives in the per-request effective route context. We
    read that context when it is there and fall back to the route's own path (older FastAPI, where the
    included route already carries the prefix); tests/server/test_tokens.py pins the result.
    """
    fastapi_scope = scope.get("fastapi")
    context = fastapi_scope.get("effective_route_context") if isinstance(fastapi_scope, dict) else None
    template = getattr(context, "path_format", None) or getattr(context, "path", None)
    if isinstance(template, str) and template:
        return template
    route = scope.get("route")
    path = getattr(route, "path_format", None) or getattr(route, "path", None)
    return path if isinstance(path, str) and path else "unmatched"


class _CountRequests:
    """Pure ASGI middleware counting requests and their latency per route template.

    Not ``@app.middleware("http")``: Starlette's ``BaseHTTPMiddleware`` runs the rest of the app in a task
    of its own and copies the body through a stream, a fixed cost on every request (BENCHMARKS.md).
    """

    def __init__(
        self, app: ASGIApp, requests: Counter, latency: Histogram, rendered: _RenderedRequests
    ) -> None:
        self.app, self.requests, self.latency, self.rendered = app, requests, latency, rendered

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()
        status = 500

        async def send_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_status)
        finally:
            path = route_template(scope)
            method = scope.get("method", "")
            self.requests.labels(method, path, str(status)).inc()
            self.latency.labels(method, path).observe(time.perf_counter() - started)
            self.rendered.saw((method, path, status))


class _RenderedRequests:
    """The request metrics' text, rendered at most once per ``max_age_s`` unless a new label set appeared."""

    def __init__(self, registry: CollectorRegistry, max_age_s: float = REQUEST_METRICS_MAX_AGE_S) -> None:
        self.registry, self.max_age_s = registry, max_age_s
        self._labels: set[tuple[str, str, int]] = set()
        self._lock = threading.Lock()
        self._text, self._at, self._labels_at = b"", -float("inf"), -1

    def saw(self, labels: tuple[str, str, int]) -> None:
        if labels not in self._labels:
            self._labels.add(labels)

    def text(self) -> bytes:
        with self._lock:  # concurrent scrapes share one rendering
            now = time.monotonic()
            if now - self._at >= self.max_age_s or len(self._labels) != self._labels_at:
                self._labels_at = len(self._labels)
                self._text, self._at = generate_latest(self.registry), now
            return self._text


def _every_process(requests_registry: CollectorRegistry) -> CollectorRegistry:
    """What a scrape renders of the request metrics: this process's registry, or with several API processes
    a registry that reads every process's counts from ``PROMETHEUS_MULTIPROC_DIR``."""
    if not os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
        return requests_registry
    from prometheus_client import multiprocess

    merged = CollectorRegistry()
    multiprocess.MultiProcessCollector(merged)  # type: ignore[no-untyped-call]  # prometheus_client: untyped __init__
    return merged


def install_metrics(app: FastAPI) -> None:
    # ``*_created`` timestamps: a line per label set that no dashboard here reads
    prometheus_client.disable_created_metrics()  # type: ignore[no-untyped-call]  # prometheus_client: no annotation
    requests_registry, registry = CollectorRegistry(), CollectorRegistry()
    requests = Counter(
        "robobpp_http_requests", "HTTP requests", ["method", "route", "status"], registry=requests_registry
    )
    latency = Histogram(
        "robobpp_http_request_seconds",
        "HTTP request latency",
        ["method", "route"],
        buckets=LATENCY_BUCKETS,
        registry=requests_registry,
    )
    rendered = _RenderedRequests(_every_process(requests_registry))
    registry.register(_QueueCollector(app))
    state_of(app).metrics_registry = registry

    app.add_middleware(_CountRequests, requests=requests, latency=latency, rendered=rendered)

    @app.get("/metrics", include_in_schema=False)
    def metrics(request: Request) -> Response:
        # The queue's size, request counts and latencies per route are the operator's: they map activity
        # (who submits when, what is slow) for anyone else. Public only when ROBOBPP_METRICS_PUBLIC says so.
        settings = state_of(request.app).settings
        if not settings.metrics_public and not _is_admin(request, settings.effective_admin_token):
            return Response(
                "metrics need the admin token (Authorization: Bearer …)\n",
                status_code=401,
                media_type="text/plain",
                headers={"WWW-Authenticate": "Bearer"},
            )
        return Response(rendered.text() + generate_latest(registry), media_type=CONTENT_TYPE_LATEST)


def _is_admin(request: Request, admin_token: str) -> bool:
    auth = request.headers.get("authorization", "")
    token = auth[7:].strip() if auth.lower().startswith("bearer ") else ""
    return 0 < len(token) <= 256 and hmac.compare_digest(token.encode(), admin_token.encode())
