"""Participants and API tokens. Tokens are random, shown once, and stored as SHA-256 hashes."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import APIRouter, Path, Query, Request
from sqlalchemy import select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from robobpp.db import queries
from robobpp.db.models import ApiToken, Participant, utcnow
from robobpp.schemas import Me, ParticipantCreate, ParticipantPublic, TokenCreated, TokenPublic
from robobpp.server.api.deps import AdminDep, PrincipalDep, SessionDep, SettingsDep
from robobpp.server.config import Settings
from robobpp.server.principal import Principal
from robobpp.server.problems import ProblemError
from robobpp.server.services import admission

router = APIRouter(tags=["participants"])
Id = Annotated[int, Path(ge=1, le=2**31 - 1)]


def issue_token(session: SessionDep, participant: Participant) -> TokenCreated:
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


@router.post(
    "/participants",
    status_code=201,
    response_model=TokenCreated,
    summary="Create a participant and its first API token (admin)",
)
def create_participant(body: ParticipantCreate, session: SessionDep, _admin: AdminDep) -> TokenCreated:
    if session.execute(select(Participant.id).where(Participant.name == body.name)).first() is not None:
        raise ProblemError(409, "conflict", "Name taken", f"a participant named {body.name!r} already exists")
    participant = Participant(name=body.name)
    session.add(participant)
    session.flush()
    return issue_token(session, participant)


@router.post(
    "/participants/{participant_id}/tokens",
    status_code=201,
    response_model=TokenCreated,
    summary="Issue another API token for a participant (admin)",
)
def create_token(participant_id: Id, session: SessionDep, _admin: AdminDep) -> TokenCreated:
    participant = session.get(Participant, participant_id)
    if participant is None or participant.is_builtin:
        raise ProblemError(404, "not-found", "Not found", f"no participant {participant_id}")
    return issue_token(session, participant)


@router.get("/me", response_model=Me, summary="Who the token belongs to, and its quota use")
async def me(request: Request, principal: PrincipalDep, settings: SettingsDep) -> Me:
    if principal.participant is None:
        return Me(admin=principal.admin, participant=None)

    def read() -> Me:
        with request.app.state.runtime.read_session() as session:
            return me_of(session, principal, settings)

    return await run_in_threadpool(read)


def me_of(session: Session, principal: Principal, settings: Settings) -> Me:
    """Who ``principal`` is and its quota use (the API's /me and the account page)."""
    if principal.participant is None:
        return Me(admin=principal.admin, participant=None)
    return Me(
        admin=principal.admin,
        participant=ParticipantPublic.model_validate(principal.participant, from_attributes=True),
        quota=admission.quota_use(session, principal.participant.id, settings),
    )


@router.get(
    "/tokens",
    response_model=list[TokenPublic],
    summary="Your API tokens (admin: every participant's, or one participant's)",
)
def list_tokens(
    session: SessionDep,
    principal: PrincipalDep,
    participant_id: Annotated[int | None, Query(ge=1, le=2**31 - 1)] = None,
) -> list[TokenPublic]:
    query = select(ApiToken).order_by(ApiToken.id)
    owner = participant_id if principal.admin else principal.participant_id
    if owner is not None:
        query = query.where(ApiToken.participant_id == owner)
    return [TokenPublic.model_validate(t, from_attributes=True) for t in session.execute(query).scalars()]


@router.delete(
    "/tokens/{token_id}",
    response_model=TokenPublic,
    summary="Revoke an API token (its owner or the admin); it stops working at once",
)
def revoke_token(token_id: Id, session: SessionDep, principal: PrincipalDep) -> TokenPublic:
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
