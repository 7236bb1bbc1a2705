"""Browser sessions: a signed, HttpOnly cookie that names an API token's row (never the token itself).

The cookie holds ``{"n": csrf nonce, "t": token id}`` (a participant) or ``{"n", "a": 1}`` (the
operator), signed with itsdangerous under a key derived from the admin token: rotating the admin token
signs every browser out. Each request re-reads the token row, so revoking a token ends its sessions at
once. Forms carry the nonce as a CSRF token; a POST without the matching nonce (or from another origin)
is refused. SameSite=Lax keeps the cookie off cross-site POSTs as a second line of defence.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

from fastapi import Request, Response
from itsdangerous import BadSignature, URLSafeTimedSerializer
from starlette.concurrency import run_in_threadpool

from robobpp.db.models import ApiToken
from robobpp.server.config import Settings

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

    @property
    def signed_in(self) -> bool:
        return self.admin or self.participant_id is not None

    @property
    def csrf(self) -> str:
        return self.nonce


def _serializer(settings: Settings) -> URLSafeTimedSerializer:
    key = hmac.new(settings.effective_admin_token.encode(), b"robobpp web session v1", hashlib.sha256)
    return URLSafeTimedSerializer(key.digest(), salt="robobpp.session")


def _load(request: Request) -> dict[str, Any]:
    raw = request.cookies.get(COOKIE)
    if not raw or len(raw) > 1024:
        return {}
    try:
        data = _serializer(request.app.state.settings).loads(raw, max_age=MAX_AGE_S)
    except BadSignature:  # also expired (SignatureExpired is a BadSignature)
        return {}
    return data if isinstance(data, dict) else {}


def viewer(request: Request) -> Viewer:
    """The request's viewer, looked up once per request (the token row decides, not the cookie alone)."""
    cached = getattr(request.state, "viewer", None)
    if cached is not None:
        return cached
    data = _load(request)
    nonce = data.get("n") if isinstance(data.get("n"), str) else ""
    found = Viewer(nonce=nonce)
    if data.get("a") == 1:
        found = Viewer(nonce=nonce, admin=True, name="operator")
    elif isinstance(data.get("t"), int):
        with request.app.state.runtime.read_session() as session:
            row = session.get(ApiToken, data["t"])
            if row is not None and row.revoked_at is None and not row.participant.is_builtin:
                found = Viewer(nonce=nonce, participant_id=row.participant_id, name=row.participant.name,
                               token_id=row.id)  # fmt: skip
    request.state.viewer = found
    return found


async def load_viewer(request: Request) -> Viewer:
    """Router dependency: resolve (and cache) the viewer before the handler opens its own transaction.

    Async, so an anonymous visitor or the operator (whose cookie alone decides) costs no worker thread;
    a participant's session reads its token row in one."""
    if getattr(request.state, "viewer", None) is None and isinstance(_load(request).get("t"), int):
        return await run_in_threadpool(viewer, request)
    return viewer(request)


def start(request: Request, response: Response, *, token_id: int | None = None, admin: bool = False) -> None:
    """Sign in: a fresh session (new nonce, so a nonce seen before sign-in is worth nothing after)."""
    data: dict[str, Any] = {"n": secrets.token_urlsafe(24)}
    if admin:
        data["a"] = 1
    else:
        data["t"] = token_id
    _write(request, response, data)


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
    response.delete_cookie(COOKIE, path=_path(request), secure=_https(request), httponly=True, samesite="lax")


def csrf_ok(request: Request, token: str) -> bool:
    """The form's token matches this browser's session, and the POST comes from this site."""
    origin = request.headers.get("origin")
    if origin and origin != "null" and urlsplit(origin).netloc != request.headers.get("host", ""):
        return False
    nonce = viewer(request).nonce
    return bool(nonce) and hmac.compare_digest(nonce.encode(), token.encode())


def _write(request: Request, response: Response, data: dict[str, Any]) -> None:
    value = _serializer(request.app.state.settings).dumps(data)
    response.set_cookie(COOKIE, value, max_age=MAX_AGE_S, path=_path(request), secure=_https(request),
                        httponly=True, samesite="lax")  # fmt: skip


def _https(request: Request) -> bool:
    # Behind a TLS proxy, uvicorn's --proxy-headers turns X-Forwarded-Proto into this scheme.
    return request.url.scheme == "https"


def _path(request: Request) -> str:
    return (str(request.scope.get("root_path", "")).rstrip("/")) or "/"
