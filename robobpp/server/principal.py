"""Who is calling: what the routes learn from the bearer token (api/deps.py) or the page session, and what the
services decide with (quota, ownership, operator-only actions). Tokens are checked here, once, for the API's
bearer auth, the pages' sign-in and the pull relay alike."""

from __future__ import annotations

import hmac
from dataclasses import dataclass

from starlette.requests import HTTPConnection

from robobpp.db import queries
from robobpp.db.models import Participant
from robobpp.server.config import Settings
from robobpp.server.ratelimit import AuthLimits, client_address, token_prefix
from robobpp.server.runtime import Runtime


@dataclass(slots=True)
class Principal:
    """Who is calling: a participant, or the operator holding the admin token."""

    participant: Participant | None
    admin: bool = False
    #: The API token's row id (participants only): the pages' signed session names it, never the token.
    token_id: int | None = None

    @property
    def participant_id(self) -> int | None:
        return self.participant.id if self.participant else None


# The services import Principal, and the app's state names the services' caches: this module reads the state
# untyped (robobpp.server.state.AppState declares what it reads), so that the state can name the services.
def auth_limit(request: HTTPConnection) -> AuthLimits:
    limit: AuthLimits = request.app.state.auth_limit
    return limit


def auth_refused_for(request: HTTPConnection, token: str = "") -> float:
    """Seconds before ``token`` from this client is even looked at (too many wrong tokens from its address,
    with its prefix, or for its participant: :mod:`robobpp.server.ratelimit`); 0: none."""
    return auth_limit(request).retry_after(client_address(request), token)


def is_admin_token(request: HTTPConnection, token: str) -> bool:
    settings: Settings = request.app.state.settings
    return 0 < len(token) <= 256 and hmac.compare_digest(
        token.encode(), settings.effective_admin_token.encode()
    )


def principal_for_token(request: HTTPConnection, token: str) -> Principal | None:
    """Who holds ``token`` (the admin token or a live API token), or None. Shared by the API's bearer
    auth, the pages' sign-in and the pull relay, so all accept exactly the same tokens — and count every
    wrong one against the client's address, the token's prefix and the participant holding a live token with
    that prefix (:mod:`robobpp.server.ratelimit`)."""
    owner = None
    if token and len(token) <= 256:
        if is_admin_token(request, token):
            return Principal(None, admin=True)
        # A short transaction of its own: handlers that call the network (URL probes) must not hold one open.
        runtime: Runtime = request.app.state.runtime
        with runtime.read_session() as session:
            row = queries.active_token(session, token)
            if row is not None:
                return Principal(row.participant, token_id=row.id)
            prefix = token_prefix(token)
            if prefix is not None:
                owner = queries.live_prefix_owner(session, prefix)
    auth_limit(request).failed(client_address(request), token if len(token) <= 256 else "", owner)
    return None
