"""Prometheus ``/metrics``: request counts and latencies, plus the evaluation queue read from SQL.

Each app has its own registry so several apps (tests) never clash over global collectors.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from typing import Any

from fastapi import FastAPI, Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector
from starlette.types import ASGIApp, Message, Receive, Scope, Send

FINISHED_SUBMISSIONS = ("completed", "failed", "cancelled")


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
            "robobpp_episodes", "Episodes queued (pending) or running", labels=["status"]
        )
        submissions = GaugeMetricFamily("robobpp_submissions", "Submissions by status", labels=["status"])
        try:
            with self.app.state.runtime.read_session() as session:
                queue, active, marker = queries.queue_snapshot(session)  # one round trip
                if self._finished is None or self._finished[0] != marker:
                    finished = queries.submission_status_counts(session, FINISHED_SUBMISSIONS)
                    self._finished = (marker, finished)
            for status, n in queue.items():
                episodes.add_metric([status], n)
            for status, n in {**active, **self._finished[1]}.items():
                submissions.add_metric([status], n)
        except Exception:  # noqa: BLE001 - a scrape must not fail because the database blinked
            pass
        yield episodes
        yield submissions
        cache = getattr(self.app.state, "board_cache", None)
        if cache is not None:
            computed = GaugeMetricFamily(
                "robobpp_board_snapshots", "Board snapshots computed by this process"
            )
            computed.add_metric([], cache.computed)
            seconds = GaugeMetricFamily("robobpp_board_snapshot_seconds",
                                        "Wall time of this process's last board snapshot computation")  # fmt: skip
            seconds.add_metric([], cache.last_seconds)
            yield computed
            yield seconds


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

    def __init__(self, app: ASGIApp, requests: Counter, latency: Histogram) -> None:
        self.app, self.requests, self.latency = app, requests, latency

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


def install_metrics(app: FastAPI) -> None:
    registry = CollectorRegistry()
    requests = Counter(
        "robobpp_http_requests", "HTTP requests", ["method", "route", "status"], registry=registry
    )
    latency = Histogram("robobpp_http_request_seconds", "HTTP request latency", ["method", "route"],
                        registry=registry)  # fmt: skip
    registry.register(_QueueCollector(app))
    app.state.metrics_registry = registry

    app.add_middleware(_CountRequests, requests=requests, latency=latency)

    @app.get("/metrics", include_in_schema=False)
    def metrics() -> Response:
        return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)
