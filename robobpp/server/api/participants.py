"""Participants and API tokens (the rules: ``services.accounts``)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, Request
from starlette.concurrency import run_in_threadpool

from robobpp.schemas import Me, ParticipantCreate, TokenCreated, TokenPublic
from robobpp.server.api.deps import AdminDep, PrincipalDep, SessionDep, SettingsDep
from robobpp.server.services import accounts
from robobpp.server.state import state_of

router = APIRouter(tags=["participants"])
Id = Annotated[int, Path(ge=1, le=2**31 - 1)]


@router.post(
    "/participants",
    status_code=201,
    response_model=TokenCreated,
    summary="Create a participant and its first API token (admin)",
)
def create_participant(body: ParticipantCreate, session: SessionDep, _admin: AdminDep) -> TokenCreated:
    return accounts.create_participant(session, body.name)


@router.post(
    "/participants/{participant_id}/tokens",
    status_code=201,
    response_model=TokenCreated,
    summary="Issue another API token for a participant (admin)",
)
def create_token(participant_id: Id, session: SessionDep, _admin: AdminDep) -> TokenCreated:
    return accounts.issue_token_for(session, participant_id)


@router.get("/me", response_model=Me, summary="Who the token belongs to, and its quota use")
async def me(request: Request, principal: PrincipalDep, settings: SettingsDep) -> Me:
    if principal.participant is None:
        return Me(admin=principal.admin, participant=None)

    def read() -> Me:
        with state_of(request.app).runtime.read_session() as session:
            return accounts.me_of(session, principal, settings)

    return await run_in_threadpool(read)


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
    return accounts.list_tokens(session, principal, participant_id)


@router.delete(
    "/tokens/{token_id}",
    response_model=TokenPublic,
    summary="Revoke an API token (its owner or the admin); it stops working at once",
)
def revoke_token(token_id: Id, session: SessionDep, principal: PrincipalDep) -> TokenPublic:
    """Idempotent (see ``services.accounts.revoke_token``)."""
    return accounts.revoke_token(session, principal, token_id)
