"""Request dependencies: a transaction per request and the caller's identity (bearer token)."""

from __future__ import annotations

import hmac
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from robobpp.db import queries
from robobpp.db.models import Participant
from robobpp.server.config import Settings
from robobpp.server.problems import ProblemError

_bearer = HTTPBearer(auto_error=False, description="An API token, or the admin token")


def get_settings(request: Request) -> Settings:
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


@dataclass(slots=True)
class Principal:
    """Who is calling: a participant, or the operator holding the admin token."""

    participant: Participant | None
    admin: bool = False

    @property
    def participant_id(self) -> int | None:
        return self.participant.id if self.participant else None


def _unauthorized(detail: str) -> ProblemError:
    return ProblemError(401, "unauthorized", "Unauthorized", detail, headers={"WWW-Authenticate": "Bearer"})


def get_principal(
    request: Request,
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Principal:
    if credentials is None or not credentials.credentials:
        raise _unauthorized("send an API token as 'Authorization: Bearer <token>'")
    token = credentials.credentials
    if len(token) > 256:
        raise _unauthorized("the API token is not valid")
    if hmac.compare_digest(token.encode(), settings.effective_admin_token.encode()):
        return Principal(None, admin=True)
    # A short transaction of its own: handlers that call the network (URL probes) must not hold one open.
    with request.app.state.runtime.read_session() as session:
        participant = queries.participant_for_token(session, token)
    if participant is None:
        raise _unauthorized("the API token is not valid (unknown or revoked)")
    return Principal(participant)


def require_admin(principal: Annotated[Principal, Depends(get_principal)]) -> Principal:
    if not principal.admin:
        raise ProblemError(403, "forbidden", "Forbidden", "this operation needs the admin token")
    return principal


PrincipalDep = Annotated[Principal, Depends(get_principal)]
AdminDep = Annotated[Principal, Depends(require_admin)]
