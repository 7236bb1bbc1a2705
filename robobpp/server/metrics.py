"""Prometheus ``/metrics``: request counts and latencies, plus the evaluation queue read from SQL.

Each app has its own registry so several apps (tests) never clash over global collectors.
"""

from __future__ import annotations

import time
from collections.abc import Iterable

from fastapi import FastAPI, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector


class _QueueCollector(Collector):
    """Episodes and submissions by status, counted at scrape time (SQL is the record of truth)."""

    def __init__(self, app: FastAPI) -> None:
        self.app = app

    def collect(self) -> Iterable[GaugeMetricFamily]:
        from robobpp.db import queries

        episodes = GaugeMetricFamily("robobpp_episodes", "Episodes by status", labels=["status"])
        submissions = GaugeMetricFamily("robobpp_submissions", "Submissions by status", labels=["status"])
        try:
            with self.app.state.runtime.session() as session:
                for status, n in queries.episode_status_counts(session).items():
                    episodes.add_metric([status], n)
                for status, n in queries.submission_status_counts(session).items():
                    submissions.add_metric([status], n)
        except Exception:  # noqa: BLE001 - a scrape must not fail because the database blinked
            pass
        yield episodes
        yield submissions


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
        route = request.scope.get("route")
        path = getattr(route, "path", "unmatched")
        requests.labels(request.method, path, str(response.status_code)).inc()
        latency.labels(request.method, path).observe(time.perf_counter() - started)
        return response

    @app.get("/metrics", include_in_schema=False)
    def metrics() -> Response:
        return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)
