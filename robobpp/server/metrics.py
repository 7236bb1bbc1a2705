"""Prometheus ``/metrics``: request counts and latencies, plus the evaluation queue read from SQL.

Each app has its own registry so several apps (tests) never clash over global collectors.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from typing import Any

from fastapi import FastAPI, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector


class _QueueCollector(Collector):
    """The queue (episodes pending or running) and submissions by status, counted at scrape time from
    indexes (SQL is the record of truth); finished episodes are not counted: see ``queries.QUEUE_STATUSES``."""

    def __init__(self, app: FastAPI) -> None:
        self.app = app

    def collect(self) -> Iterable[GaugeMetricFamily]:
        from robobpp.db import queries

        episodes = GaugeMetricFamily(
            "robobpp_episodes", "Episodes queued (pending) or running", labels=["status"]
        )
        submissions = GaugeMetricFamily("robobpp_submissions", "Submissions by status", labels=["status"])
        try:
            with self.app.state.runtime.read_session() as session:
                for status, n in queries.episode_status_counts(session).items():
                    episodes.add_metric([status], n)
                for status, n in queries.submission_status_counts(session).items():
                    submissions.add_metric([status], n)
        except Exception:  # noqa: BLE001 - a scrape must not fail because the database blinked
            pass
        yield episodes
        yield submissions


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


def install_metrics(app: FastAPI) -> None:
    registry = CollectorRegistry()
    requests = Counter(
        "robobpp_http_requests", "HTTP requests", ["method", "route", "status"], registry=registry
    )
    latency = Histogram("robobpp_http_request_seconds", "HTTP request latency", ["method", "route"],
                        registry=registry)  # fmt: skip
    registry.register(_QueueCollector(app))
    app.state.metrics_registry = registry

    @app.middleware("http")
    async def _count(request: Request, call_next):  # type: ignore[no-untyped-def]
        started = time.perf_counter()
        response = await call_next(request)
        path = route_template(request.scope)
        requests.labels(request.method, path, str(response.status_code)).inc()
        latency.labels(request.method, path).observe(time.perf_counter() - started)
        return response

    @app.get("/metrics", include_in_schema=False)
    def metrics() -> Response:
        return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)
