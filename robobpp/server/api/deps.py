"""Request dependencies: a transaction per request and the caller's identity (bearer token)."""

from __future__ import annotations

import hmac
from collections.abc import Callable, Iterator
from typing import Annotated, TypeVar

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from robobpp.db import queries
from robobpp.server.config import Settings
from robobpp.server.principal import Principal
from robobpp.server.problems import ProblemError
from robobpp.server.ratelimit import FailureLimit, client_address

T = TypeVar("T")
_bearer = HTTPBearer(auto_error=False, description="An API token, or the admin token")


async def get_settings(request: Request) -> Settings:  # async: no worker thread for an attribute read
    return request.app.state.settings


#: Methods whose handlers only read: their transaction never waits for the writers (db/session.py).
READ_METHODS = frozenset({"GET", "HEAD"})


def get_session(request: Request) -> Iterator[Session]:
    """One transaction per request: committed after the handler, rolled back if it raises."""
    runtime = request.app.state.runtime
    with runtime.read_session() if request.method in READ_METHODS else runtime.session() as session:
        yield session


SessionDep = Annotated[Session, Depends(get_session)]
SettingsDep = Annotated[Settings, Depends(get_settings)]


def _unauthorized(detail: str) -> ProblemError:
    return ProblemError(401, "unauthorized", "Unauthorized", detail, headers={"WWW-Authenticate": "Bearer"})


def auth_limit(request: Request) -> FailureLimit:
    limit = getattr(request.app.state, "auth_limit", None)
    if limit is None:
        settings: Settings = request.app.state.settings
        limit = request.app.state.auth_limit = FailureLimit(settings.auth_failures_per_minute, 60.0)
    return limit


def auth_refused_for(request: Request) -> float:
    """Seconds this client must wait before its next token is even looked at (too many wrong ones); 0: none."""
    return auth_limit(request).retry_after(client_address(request))


def too_many_failures(wait_s: float) -> ProblemError:
    return ProblemError(
        429,
        "too-many-failures",
        "Too many failed authentications",
        f"too many wrong tokens from this address; retry in {wait_s:.0f} s",
        headers={"Retry-After": str(max(1, round(wait_s)))},
    )


def principal_for_token(request: Request, token: str) -> Principal | None:
    """Who holds ``token`` (the admin token or a live API token), or None. Shared by the API's bearer
    auth, the pages' sign-in and the pull relay, so all accept exactly the same tokens — and count every
    wrong one against the client's address (:mod:`robobpp.server.ratelimit`)."""
    settings: Settings = request.app.state.settings
    if token and len(token) <= 256:
        if hmac.compare_digest(token.encode(), settings.effective_admin_token.encode()):
            return Principal(None, admin=True)
        # A short transaction of its own: handlers that call the network (URL probes) must not hold one open.
        with request.app.state.runtime.read_session() as session:
            row = queries.active_token(session, token)
            if row is not None:
                return Principal(row.participant, token_id=row.id)
    auth_limit(request).failed(client_address(request))
    return None


async def get_principal(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Principal:
    """Async: the admin token is checked on the event loop; a participant's token row is read in a
    worker thread (every request re-reads it, so a revoked token stops working at once)."""
    if credentials is None or not credentials.credentials:
        raise _unauthorized("send an API token as 'Authorization: Bearer <token>'")
    wait = auth_refused_for(request)
    if wait:
        raise too_many_failures(wait)
    token = credentials.credentials
    settings: Settings = request.app.state.settings
    if 0 < len(token) <= 256 and hmac.compare_digest(token.encode(), settings.effective_admin_token.encode()):
        return Principal(None, admin=True)
    principal = await run_in_threadpool(principal_for_token, request, token)
    if principal is None:
        raise _unauthorized("the API token is not valid (unknown or revoked)")
    return principal


async def require_admin(principal: Annotated[Principal, Depends(get_principal)]) -> Principal:
    if not principal.admin:
        raise ProblemError(403, "forbidden", "Forbidden", "this operation needs the admin token")
    return principal


PrincipalDep = Annotated[Principal, Depends(get_principal)]
AdminDep = Annotated[Principal, Depends(require_admin)]


async def in_read_session(request: Request, work: Callable[[Session], T]) -> T:
    """``work`` in one worker thread with one read-only transaction: a route that must read SQL costs one
    thread hand-off, not one per dependency (the session's opening and closing, the handler)."""

    def run() -> T:
        with request.app.state.runtime.read_session() as session:
            return work(session)

    return await run_in_threadpool(run)
