"""The FastAPI application factory: JSON API, pages (when present), static files, health and metrics.

``create_app(settings)`` builds an app bound to one database; its lifespan applies migrations, seeds the
built-in participant and baselines, builds the private split if absent and starts the local worker pool.
Nothing happens at import time, so tests can build as many apps as they like.
"""

from __future__ import annotations

import importlib
import logging
import sys
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from fastapi import FastAPI, Request
from fastapi.staticfiles import StaticFiles

from robobpp.server import problems
from robobpp.server.config import Settings
from robobpp.server.headers import SecurityHeaders
from robobpp.server.limits import BodySizeLimit
from robobpp.server.prometheus import install_metrics
from robobpp.server.state import AppState

if TYPE_CHECKING:  # both executors are imported only when the server starts one (Celery is slow to import)
    from robobpp.boards.worker import BoardWorker, WorkerProcess
    from robobpp.server.runtime import Runtime
    from robobpp.worker.celery_executor import CeleryExecutor
    from robobpp.worker.local import LocalExecutor

log = logging.getLogger("robobpp.server")
T = TypeVar("T")
#: How long a starting server waits for its board worker's first publication when the database has none.
FIRST_PUBLICATION_S = 60.0

STATIC_DIR = Path(__file__).resolve().parent.parent / "web" / "static"


def _include_pages(app: FastAPI) -> None:
    """The HTML pages live in their own module (another area); include them when they exist."""
    try:
        pages = importlib.import_module("robobpp.server.pages")
    except ModuleNotFoundError as exc:
        if exc.name != "robobpp.server.pages":
            raise
        return
    router = getattr(pages, "router", None)
    if router is not None:
        app.include_router(router)


def start_executor(settings: Settings) -> CeleryExecutor | LocalExecutor | None:
    """Start what runs the episodes: the Celery dispatcher when a broker is configured (the episodes run on
    Celery workers), else the local worker pool; ``None`` when there is neither."""
    executor: CeleryExecutor | LocalExecutor
    if settings.broker_url:
        from robobpp.worker.celery_executor import executor_from_settings

        executor = executor_from_settings(settings)
    elif settings.workers > 0:
        from robobpp.worker.local import LocalExecutor
        from robobpp.worker.options import worker_options

        executor = LocalExecutor(worker_options(settings), settings.workers)
    else:
        return None
    executor.start()
    return executor


def make_state(settings: Settings) -> AppState:
    """Every part of an app's state, made before it serves (the lifespan starts what runs: workers, board
    worker, the relay's bus on its first client)."""
    from robobpp.server.api.leaderboards import make_board_cache
    from robobpp.server.probes import ProbeGate
    from robobpp.server.ratelimit import AuthLimits
    from robobpp.server.relay_hub import PullHub, make_bus
    from robobpp.server.runtime import Runtime
    from robobpp.server.services.submissions import FinishedViews

    state = AppState()
    state.settings = settings
    state.runtime = Runtime(settings)
    state.probe_gate = ProbeGate(
        settings.probe_concurrency,
        settings.probe_per_participant,
        min(settings.probe_timeout_s, settings.step_timeout_s),
    )
    state.auth_limit = AuthLimits(settings.auth_failures_per_minute, 60.0)
    state.finished_views = FinishedViews()
    state.operator_rows = None
    state.pull_hub = PullHub(make_bus(settings.pull_bus_url, settings.sqlalchemy_url))
    state.board_cache = make_board_cache(state.runtime)
    state.board_worker = None
    state.static_pages = {}
    return state


def create_app(
    settings: Settings | None = None, *, start_workers: bool | None = None, first_start: bool = True
) -> FastAPI:
    """Build the service. ``start_workers=False`` serves the API only (tests, API-only replicas);
    ``first_start=False`` skips the start-up's migrations and seeding (done once by ``robobpp serve``'s
    supervising process before it starts several API processes: server/processes.py)."""
    settings = settings or Settings()
    # With a broker the server dispatches episodes to Celery workers (no local pool); see worker/celery_*.py.
    run_workers = (
        (settings.workers > 0 or bool(settings.broker_url)) if start_workers is None else start_workers
    )

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        from robobpp.server.bootstrap import bootstrap

        runtime = state.runtime
        # threads coming back from SQL take the GIL from the event loop within this long (CPython: 5 ms,
        # which under 20 readers queued every SQL-reading route behind the loop; BENCHMARKS.md)
        sys.setswitchinterval(settings.switch_interval_s)
        if settings.api_threads:
            import anyio.to_thread

            anyio.to_thread.current_default_thread_limiter().total_tokens = settings.api_threads
        if first_start:
            await _run_sync(bootstrap, runtime)
        from robobpp.server.api.leaderboards import make_board_cache

        # the boards are computed by one board worker per deployment and published in SQL; this process
        # reads them (boards/worker.py, boards/reader.py)
        board_worker = state.board_worker = start_board_worker(runtime)
        if board_worker is not None:
            from robobpp.boards.worker import await_first_publication

            await _run_sync(await_first_publication, runtime.read_session, FIRST_PUBLICATION_S)
        if board_worker is not None:  # the reader made with the app, now woken by this process's worker
            state.board_cache = make_board_cache(runtime, board_worker.wake)
        executor = start_executor(settings) if run_workers else None
        if (
            executor is not None
        ):  # else runtime.executor stays as given (server/processes.py: the supervisor's)
            runtime.executor = executor
        progress = None
        if first_start and run_workers:  # the process that started the workers logs their progress
            from robobpp.server.services.progress import ProgressLog

            progress = ProgressLog(
                runtime.read_session, settings.workers, per_worker=settings.episodes_per_worker
            ).start()
        try:
            yield
        finally:
            if progress is not None:
                progress.stop()
            if executor is not None:
                executor.stop()
            state.probe_gate.shutdown()
            await state.pull_hub.close()  # the relay's bus (its Redis subscription, when it has one)
            if board_worker is not None:
                await _run_sync(board_worker.stop)
            runtime.dispose()

    app = FastAPI(
        title="robobpp evaluation service",
        version="1",
        summary="Closed-loop evaluation of robotic online 3D bin packing policies (RoboBPP).",
        lifespan=lifespan,
        docs_url=None,  # served below from the vendored Swagger UI: /docs works with no internet access
        openapi_url="/openapi.json",
    )
    app.state = state = make_state(settings)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes, timeout_s=settings.body_timeout_s)
    app.add_middleware(SecurityHeaders)
    problems.install(app)
    install_metrics(app)

    from robobpp.server.api import router as api_router
    from robobpp.server.api.health import router as health_router

    app.include_router(health_router)
    app.include_router(api_router, prefix="/api/v1")
    _include_pages(app)
    if STATIC_DIR.is_dir():
        app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    _include_docs(app)
    return app


def _include_docs(app: FastAPI) -> None:
    """Swagger UI at /docs from ``web/static/vendor/swagger-ui`` instead of FastAPI's default CDN."""
    from fastapi.openapi.docs import get_swagger_ui_html
    from fastapi.responses import HTMLResponse

    @app.get("/docs", include_in_schema=False)
    async def docs(request: Request) -> HTMLResponse:
        page = get_swagger_ui_html(
            openapi_url="/openapi.json",
            title=f"{app.title} — API",
            swagger_js_url="/static/vendor/swagger-ui/swagger-ui-bundle.js",
            swagger_css_url="/static/vendor/swagger-ui/swagger-ui.css",
            swagger_favicon_url="/static/vendor/swagger-ui/favicon-32x32.png",
        )
        # Swagger UI's page is not one of ours: a bar in the site's colours leads back to it.
        base = str(request.scope.get("root_path", "")).rstrip("/")
        bar = (
            '<nav data-role="site-bar" aria-label="Site" style="background:#0f172a;padding:0.6rem 1.5rem;'
            f'font:15px system-ui,sans-serif"><a href="{base}/" style="color:#fff;font-weight:700;'
            f'text-decoration:none">← robobpp</a> <a href="{base}/" style="color:#cbd5e1;margin-left:1rem">'
            f'Leaderboard</a> <a href="{base}/protocol" style="color:#cbd5e1;margin-left:1rem">Take part</a></nav>'
        )
        return HTMLResponse(bytes(page.body).decode().replace("<body>", "<body>" + bar, 1))


async def _run_sync(fn: Callable[..., T], *args: Any) -> T:
    from starlette.concurrency import run_in_threadpool

    return await run_in_threadpool(fn, *args)


def start_board_worker(runtime: Runtime) -> BoardWorker | WorkerProcess | None:
    """This process's candidate board worker (``ROBOBPP_BOARD_WORKER``), started: of all candidates of a
    deployment, the one that claims a track's publication computes it (boards/worker.py)."""
    from robobpp.boards.worker import BoardPublisher, BoardWorker, WorkerProcess

    settings = runtime.settings
    boards = (tuple(settings.datasets), tuple(settings.enabled_settings))
    worker: BoardWorker | WorkerProcess
    if settings.board_worker == "process":
        worker = WorkerProcess(
            settings.sqlalchemy_url, *boards, poll_s=settings.board_poll_s, full_s=settings.board_full_s
        )
    elif settings.board_worker == "thread":
        worker = BoardWorker(
            BoardPublisher(runtime.read_session, runtime.session, *boards),
            poll_s=settings.board_poll_s,
            full_s=settings.board_full_s,
        )
    else:
        return None
    worker.start()
    return worker
