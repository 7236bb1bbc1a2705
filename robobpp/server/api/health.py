"""Liveness and readiness: ``/healthz`` answers 200 only when the database answers, and, in an API process of
``robobpp serve --server-workers N``, while its supervisor is there (server/processes.py)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse
from sqlalchemy import text

from robobpp.server.state import state_of

router = APIRouter(tags=["health"])


@router.get("/healthz", summary="Health check (database reachable, workers alive)")
def healthz(request: Request) -> JSONResponse:
    runtime = state_of(request.app).runtime
    try:
        with runtime.read_engine.connect() as connection:
            connection.execute(text("SELECT 1"))
    except Exception as exc:  # noqa: BLE001 - any database failure means "not healthy"
        return JSONResponse({"status": "unavailable", "database": type(exc).__name__}, status_code=503)
    executor = runtime.executor
    supervised = getattr(executor, "supervisor_alive", None)  # an API process of --server-workers N
    if supervised is not None and not supervised():  # it is ending: nothing dispatches what it would accept
        return JSONResponse({"status": "unavailable", "supervisor": "gone"}, status_code=503)
    workers = executor.alive() if executor is not None else 0
    return JSONResponse({"status": "ok", "database": "ok", "workers": workers})
