"""Participants' accounts: who a principal is with its quota use, and its API tokens (issued, listed, revoked).
The JSON API and the pages both call these, so a token revoked on the account page is revoked exactly as by
``DELETE /tokens/{id}``. Tokens are random, shown once, and stored as SHA-256 hashes."""

from __future__ import annotations

import secrets

from sqlalchemy import select
from sqlalchemy.orm import Session

from robobpp.db import queries
from robobpp.db.models import ApiToken, Participant, utcnow
from robobpp.schemas import Me, ParticipantPublic, TokenCreated, TokenPublic
from robobpp.server.config import Settings
from robobpp.server.principal import Principal
from robobpp.server.problems import ProblemError
from robobpp.server.services import admission


def issue_token(session: Session, participant: Participant) -> TokenCreated:
    token = "rbp_" + secrets.token_urlsafe(32)
    row = ApiToken(participant_id=participant.id, token_hash=queries.hash_token(token), prefix=token[:10])
    session.add(row)
    session.flush()
    return TokenCreated(
        participant=ParticipantPublic.model_validate(participant, from_attributes=True),
        token=token,
        prefix=token[:10],
        id=row.id,
    )


def create_participant(session: Session, name: str) -> TokenCreated:
    """A new participant and its first token (the operator's)."""
    if session.execute(select(Participant.id).where(Participant.name == name)).first() is not None:
        raise ProblemError(409, "conflict", "Name taken", f"a participant named {name!r} already exists")
    participant = Participant(name=name)
    session.add(participant)
    session.flush()
    return issue_token(session, participant)


def issue_token_for(session: Session, participant_id: int) -> TokenCreated:
    """Another token for a participant (the operator's); the built-in baselines' participant has none."""
    participant = session.get(Participant, participant_id)
    if participant is None or participant.is_builtin:
        raise ProblemError(404, "not-found", "Not found", f"no participant {participant_id}")
    return issue_token(session, participant)


def me_of(session: Session, principal: Principal, settings: Settings) -> Me:
    """Who ``principal`` is and its quota use (the API's /me and the account page)."""
    if principal.participant is None:
        return Me(admin=principal.admin, participant=None)
    return Me(
        admin=principal.admin,
        participant=ParticipantPublic.model_validate(principal.participant, from_attributes=True),
        quota=admission.quota_use(session, principal.participant.id, settings),
    )


def list_tokens(
    session: Session, principal: Principal, participant_id: int | None = None
) -> list[TokenPublic]:
    """The principal's own tokens; the operator's: every participant's, or ``participant_id``'s."""
    query = select(ApiToken).order_by(ApiToken.id)
    owner = participant_id if principal.admin else principal.participant_id
    if owner is not None:
        query = query.where(ApiToken.participant_id == owner)
    return [TokenPublic.model_validate(t, from_attributes=True) for t in session.execute(query).scalars()]


def revoke_token(session: Session, principal: Principal, token_id: int) -> TokenPublic:
    """Idempotent: revoking a revoked token answers it unchanged (its first ``revoked_at`` is kept).

    Another participant's token answers 404 like a missing one, so ids reveal nothing. The row stays
    (with ``revoked_at``): it records that the token existed, and its hash can never authenticate again.
    """
    row = session.execute(
        select(ApiToken).where(ApiToken.id == token_id).with_for_update()
    ).scalar_one_or_none()
    if row is None or not (principal.admin or row.participant_id == principal.participant_id):
        raise ProblemError(404, "not-found", "Not found", f"no API token {token_id} visible to this token")
    if row.revoked_at is None:
        row.revoked_at = utcnow()
        session.flush()
    return TokenPublic.model_validate(row, from_attributes=True)
