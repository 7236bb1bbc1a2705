"""Browser sessions: a signed, HttpOnly cookie that names an API token's row (never the token itself).

The cookie holds ``{"n": csrf nonce, "s": session id}`` (``web_sessions``: a participant's, naming the token
it signed in with, or the operator's), signed with itsdangerous under a key derived from the admin token:
rotating the admin token signs every browser out. Each request re-reads the session row and the token row,
so signing out (which revokes the row) or revoking the token ends the session at once, for every copy of
the cookie. Forms carry the nonce as a CSRF token; a POST without the matching nonce (or from another origin)
is refused. SameSite=Lax keeps the cookie off cross-site POSTs as a second line of defence.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timedelta
from functools import cache, lru_cache
from typing import Any, TypeVar
from urllib.parse import urlsplit

from fastapi import Request, Response
from itsdangerous import BadSignature, URLSafeTimedSerializer
from sqlalchemy import Select, bindparam, select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from robobpp.db.models import ApiToken, Participant, WebSession, utcnow
from robobpp.server.config import Settings
from robobpp.server.state import state_of

COOKIE = "robobpp_session"
#: A browser session lasts at most this long; signing in again starts a new one.
MAX_AGE_S = 12 * 3600


@dataclass(frozen=True, slots=True)
class Viewer:
    """Who is looking at a page: anonymous, a participant (through one of its tokens) or the operator."""

    nonce: str = ""
    participant_id: int | None = None
    name: str | None = None
    token_id: int | None = None
    admin: bool = False
    session_id: int | None = None

    @property
    def signed_in(self) -> bool:
        return self.admin or self.participant_id is not None

    @property
    def csrf(self) -> str:
        return self.nonce


def _serializer(settings: Settings) -> URLSafeTimedSerializer:
    return _serializer_for(settings.effective_admin_token)


@lru_cache(maxsize=4)
def _serializer_for(admin_token: str) -> URLSafeTimedSerializer:
    """Built once per admin token (not per request: the key derivation is a third of reading a cookie)."""
    key = hmac.new(admin_token.encode(), b"robobpp web session v1", hashlib.sha256)
    return URLSafeTimedSerializer(key.digest(), salt="robobpp.session")


def _load(request: Request) -> dict[str, Any]:
    raw = request.cookies.get(COOKIE)
    if not raw or len(raw) > 1024:
        return {}
    try:
        data = _serializer(state_of(request.app).settings).loads(raw, max_age=MAX_AGE_S)
    except BadSignature:  # also expired (SignatureExpired is a BadSignature)
        return {}
    return data if isinstance(data, dict) else {}


def viewer(request: Request, session: Session | None = None) -> Viewer:
    """The request's viewer, looked up once per request (the session row and the token row decide, not the
    cookie alone). ``session``: the handler's own read transaction, when the viewer was left to it
    (:func:`resolved_in_handler`); otherwise a transaction of its own."""
    cached: Viewer | None = getattr(request.state, "viewer", None)
    if cached is not None:
        return cached
    data = _load(request)
    nonce = found if isinstance(found := data.get("n"), str) else ""
    found = Viewer(nonce=nonce)
    if isinstance(data.get("s"), int):
        with reading(request, session) as s:
            found = _signed_in(s, data["s"], nonce) or found
    request.state.viewer = found
    return found


@contextmanager
def reading(request: Request, session: Session | None) -> Iterator[Session]:
    """``session`` when the caller has a transaction open, else a read transaction of its own."""
    if session is not None:
        yield session
        return
    with state_of(request.app).runtime.read_session() as own:
        yield own


def _signed_in(session: Session, session_id: int, nonce: str) -> Viewer | None:
    """The viewer a live session row names (its token's participant, or the operator), or None."""
    row = session.execute(_session_statement(), {"id": session_id}).one_or_none()
    if row is None or row.revoked_at is not None or not _fresh(row.created_at):
        return None
    if row.admin:
        return Viewer(nonce=nonce, admin=True, name="operator", session_id=row.id)
    if (
        row.token_id is None
        or row.participant_id is None
        or row.token_revoked_at is not None
        or row.is_builtin
    ):
        return None
    return Viewer(
        nonce=nonce,
        participant_id=row.participant_id,
        name=row.name,
        token_id=row.token_id,
        session_id=row.id,
    )


@cache
def _session_statement() -> Select[
    int, bool, datetime | None, datetime, int | None, datetime | None, int, str, bool
]:
    """The session row with its token's and participant's fields: one round trip, no ORM objects (three
    lookups before; a signed-in page reads it on every request). Built once."""
    return (
        select(
            WebSession.id,
            WebSession.admin,
            WebSession.revoked_at,
            WebSession.created_at,
            WebSession.token_id,
            ApiToken.revoked_at.label("token_revoked_at"),
            ApiToken.participant_id,
            Participant.name,
            Participant.is_builtin,
        )
        .outerjoin(ApiToken, ApiToken.id == WebSession.token_id)
        .outerjoin(Participant, Participant.id == ApiToken.participant_id)
        .where(WebSession.id == bindparam("id"))
    )


def _fresh(created_at: datetime) -> bool:
    return utcnow() - created_at < timedelta(seconds=MAX_AGE_S)


F = TypeVar("F", bound=Callable[..., Any])


def resolved_in_handler(endpoint: F) -> F:
    """Marks a route whose handler reads SQL in one transaction of its own and calls
    ``viewer(request, session)`` there first: a signed-in viewer's rows are then read in that transaction,
    not in a worker-thread hand-off and a transaction of their own before it (under 20 readers each
    hand-off waits for the GIL: BENCHMARKS.md)."""
    endpoint.__dict__["_viewer_in_handler"] = True
    return endpoint


async def load_viewer(request: Request) -> Viewer | None:
    """Router dependency: resolve (and cache) the viewer before the handler opens its own transaction.

    Async, so an anonymous visitor (whose cookie alone decides) costs no worker thread; a signed-in one's
    session and token rows are read in one — or in the handler's own transaction where the route says so
    (:func:`resolved_in_handler`)."""
    if getattr(request.state, "viewer", None) is None and isinstance(_load(request).get("s"), int):
        if getattr(request.scope.get("endpoint"), "_viewer_in_handler", False):
            return None
        return await run_in_threadpool(viewer, request)
    return viewer(request)


def start(request: Request, response: Response, *, token_id: int | None = None, admin: bool = False) -> None:
    """Sign in: a new session row and a fresh nonce (a nonce seen before sign-in is worth nothing after)."""
    with state_of(request.app).runtime.session() as session:
        row = WebSession(token_id=None if admin else token_id, admin=admin)
        session.add(row)
        session.flush()
        session_id = row.id
    _write(request, response, {"n": secrets.token_urlsafe(24), "s": session_id})


def ensure_nonce(request: Request, response: Response) -> str:
    """The CSRF nonce of this browser, creating an anonymous session for a first form (the sign-in)."""
    current = viewer(request)
    if current.nonce:
        return current.nonce
    nonce = secrets.token_urlsafe(24)
    _write(request, response, {"n": nonce})
    request.state.viewer = Viewer(nonce=nonce)
    return nonce


def end(request: Request, response: Response) -> None:
    """Sign out: the session row is revoked, so a copy of the cookie (another tab, a stolen one) stops
    working too; the browser's cookie is deleted."""
    session_id = viewer(request).session_id
    if session_id is not None:
        with state_of(request.app).runtime.session() as session:
            row = session.get(WebSession, session_id)
            if row is not None and row.revoked_at is None:
                row.revoked_at = utcnow()
    response.delete_cookie(COOKIE, path=_path(request), secure=_https(request), httponly=True, samesite="lax")


def csrf_ok(request: Request, token: str) -> bool:
    """The form's token matches this browser's session, and the POST comes from this site."""
    origin = request.headers.get("origin")
    if origin and origin != "null" and urlsplit(origin).netloc != request.headers.get("host", ""):
        return False
    nonce = viewer(request).nonce
    return bool(nonce) and hmac.compare_digest(nonce.encode(), token.encode())


def _write(request: Request, response: Response, data: dict[str, Any]) -> None:
    value = _serializer(state_of(request.app).settings).dumps(data)
    response.set_cookie(
        COOKIE,
        value,
        max_age=MAX_AGE_S,
        path=_path(request),
        secure=_https(request),
        httponly=True,
        samesite="lax",
    )


def _https(request: Request) -> bool:
    # Behind a TLS proxy, uvicorn's --proxy-headers turns X-Forwarded-Proto into this scheme.
    return request.url.scheme == "https"


def _path(request: Request) -> str:
    return (str(request.scope.get("root_path", "")).rstrip("/")) or "/"
