"""The JSON API under ``/api/v1``.

The router is built on first access (module ``__getattr__``), so importing the package alone does
not pull in the routes, the database layer and the policies — that import alone costs about two seconds on a busy machine.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fastapi import APIRouter

    router: APIRouter

_router: Any = None


def _build() -> Any:
    from fastapi import APIRouter

    from robobpp.server.api import leaderboards, participants, pull, submissions

    built = APIRouter()
    built.include_router(participants.router)
    built.include_router(submissions.router)
    built.include_router(leaderboards.router)
    built.include_router(pull.router)
    return built


def __getattr__(name: str) -> Any:
    global _router
    if name != "router":
        raise AttributeError(f"module 'robobpp.server.api' has no attribute {name!r}")
    if _router is None:
        _router = _build()
    return _router
