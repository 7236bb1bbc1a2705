"""Request dependencies: a transaction per request and the caller's identity (bearer token)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Annotated, TypeVar

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from robobpp.server.config import Settings
from robobpp.server.principal import Principal, auth_refused_for, is_admin_token, principal_for_token
from robobpp.server.problems import ProblemError
from robobpp.server.state import state_of

T = TypeVar("T")
_bearer = HTTPBearer(auto_error=False, description="An API token, or the admin token")


async def get_settings(request: Request) -> Settings:  # async: no worker thread for an attribute read
    settings: Settings = state_of(request.app).settings
    return settings


#: Methods whose handlers only read: their transaction never waits for the writers (db/session.py).
READ_METHODS = frozenset({"GET", "HEAD"})


def get_session(request: Request) -> Iterator[Session]:
    """One transaction per request: committed after the handler, rolled back if it raises."""
    runtime = state_of(request.app).runtime
    with runtime.read_session() if request.method in READ_METHODS else runtime.session() as session:
        yield session


#: ``scope="function"``: the transaction commits before the response is sent. FastAPI's default ("request") ends
#: a yield dependency after sending it, so a client could read a 201 for a participant whose token the next
#: request did not find yet (seen once in CI, on PostgreSQL), and a failed commit came after a success answer.
SessionDep = Annotated[Session, Depends(get_session, scope="function")]
SettingsDep = Annotated[Settings, Depends(get_settings)]


def _unauthorized(detail: str) -> ProblemError:
    return ProblemError(401, "unauthorized", "Unauthorized", detail, headers={"WWW-Authenticate": "Bearer"})


def too_many_failures(wait_s: float) -> ProblemError:
    return ProblemError(
        429,
        "too-many-failures",
        "Too many failed authentications",
        f"too many wrong tokens from this address or for this token; retry in {wait_s:.0f} s",
        headers={"Retry-After": str(max(1, round(wait_s)))},
    )


async def get_principal(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Principal:
    """Async: the admin token is checked on the event loop; a participant's token row is read in a
    worker thread (every request re-reads it, so a revoked token stops working at once)."""
    if credentials is None or not credentials.credentials:
        raise _unauthorized("send an API token as 'Authorization: Bearer <token>'")
    token = credentials.credentials
    wait = auth_refused_for(request, token)
    if wait:
        raise too_many_failures(wait)
    if is_admin_token(request, token):  # on the event loop: no thread hand-off for the operator
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
        with state_of(request.app).runtime.read_session() as session:
            return work(session)

    return await run_in_threadpool(run)
