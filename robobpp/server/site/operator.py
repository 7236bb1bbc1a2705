"""Operator pages (admin session): participants, their API tokens and submissions.

A new token is shown once, in the answer to the POST that made it (``Cache-Control: no-store``), the
way the API shows it; afterwards only its prefix is listed.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Annotated

from fastapi import APIRouter, Depends, Path, Request
from fastapi.responses import HTMLResponse, Response
from markupsafe import Markup
from pydantic import ValidationError

from robobpp.db import queries
from robobpp.db.models import Participant
from robobpp.schemas import ParticipantCreate, TokenCreated
from robobpp.server.principal import Principal
from robobpp.server.problems import ProblemError
from robobpp.server.services import accounts
from robobpp.server.site import session as web_session
from robobpp.server.site.account import BAD_CSRF, Page, Text, problem_page, problem_text, submission_rows
from robobpp.server.site.render import not_found, redirect, refused, render, root
from robobpp.server.site.session import load_viewer, resolved_in_handler, viewer
from robobpp.server.state import state_of
from robobpp.web import environment

router = APIRouter(include_in_schema=False, dependencies=[Depends(load_viewer)])
Id = Annotated[int, Path(ge=1, le=2**31 - 1)]
ADMIN = Principal(None, admin=True)


def _is_admin(request: Request) -> bool:
    return viewer(request).admin


def _refuse_form(request: Request, csrf: str) -> Response | None:
    """The answer to an operator form's POST from anyone but the operator, or without the CSRF token."""
    if not _is_admin(request):
        return not_found(request, "There is no such page.")
    if not web_session.csrf_ok(request, csrf):
        return refused(request, BAD_CSRF)
    return None


def _participants_page(
    request: Request,
    *,
    created: TokenCreated | None = None,
    error: str | None = None,
    name: str = "",
    status_code: int = 200,
    check_admin: bool = False,
) -> Response:
    """``check_admin``: the viewer is resolved here, in this page's transaction (the GET route)."""
    state = state_of(request.app)
    with state.runtime.read_session() as session:
        if check_admin and not viewer(request, session).admin:
            return not_found(request, "There is no such page.")
        # the counts change only with a new participant, token or submission, or a revoked token
        version, kept = queries.participants_version(session), state.operator_rows
        if kept is not None and kept[0] == version:
            rows = kept[1]
        else:
            rows = tuple(queries.participant_summaries(session))
            state.operator_rows = (version, rows)
    return render(
        request,
        "operator.html",
        status_code,
        title="Participants",
        nav="operator",
        participants_table=_participants_table(root(request), rows),
        created=created,
        error=error,
        name=name,
    )


@lru_cache(maxsize=8)
def _participants_table(base: str, rows: tuple[queries.ParticipantSummary, ...]) -> Markup:
    """Rendered once per state of the rows (a hundred participants cost more to render than to read)."""
    module = environment().get_template("_participants.html").module
    # jinja2 sets a template's macros as attributes of its module at run time; its stubs cannot name them
    return Markup(module.participants_table(rows, base))  # type: ignore[attr-defined]


@router.get("/operator", response_class=HTMLResponse)
@resolved_in_handler
def operator_page(request: Request) -> Response:
    return _participants_page(request, check_admin=True)


@router.post("/operator/participants", response_class=HTMLResponse)
def create_participant(request: Request, name: Text = "", csrf: Text = "") -> Response:
    if (refusal := _refuse_form(request, csrf)) is not None:
        return refusal
    try:
        body = ParticipantCreate.model_validate({"name": name})
        with state_of(request.app).runtime.session() as session:
            created = accounts.create_participant(session, body.name)
    except (ProblemError, ValidationError) as exc:
        status = exc.status if isinstance(exc, ProblemError) else 422
        return _participants_page(request, error=problem_text(exc), name=name, status_code=status)
    return _participants_page(request, created=created, status_code=201)


def _participant_page(
    request: Request,
    participant_id: int,
    *,
    created: TokenCreated | None = None,
    status_code: int = 200,
    page: int = 1,
) -> Response:
    with state_of(request.app).runtime.read_session() as session:
        participant = session.get(Participant, participant_id)
        if participant is None:
            return not_found(request, f"There is no participant {participant_id}.")
        tokens = accounts.list_tokens(session, ADMIN, participant_id)
        rows, more = submission_rows(request, session, participant.id, page, show_participant=False)
        info = {
            "id": participant.id,
            "name": participant.name,
            "builtin": participant.is_builtin,
            "created_at": participant.created_at,
        }
    return render(
        request,
        "operator_participant.html",
        status_code,
        title=f"Participant {info['name']}",
        nav="operator",
        participant=info,
        tokens=tokens,
        rows=rows,
        created=created,
        page=page,
        more=more,
    )


@router.get("/operator/participants/{participant_id}", response_class=HTMLResponse)
def participant_page(request: Request, participant_id: Id, page: Page = 1) -> Response:
    if not _is_admin(request):
        return not_found(request, "There is no such page.")
    return _participant_page(request, participant_id, page=page)


@router.post("/operator/participants/{participant_id}/tokens", response_class=HTMLResponse)
def issue_token(request: Request, participant_id: Id, csrf: Text = "") -> Response:
    if (refusal := _refuse_form(request, csrf)) is not None:
        return refusal
    try:
        with state_of(request.app).runtime.session() as session:
            created = accounts.issue_token_for(session, participant_id)
    except ProblemError as exc:
        return problem_page(request, exc)
    return _participant_page(request, participant_id, created=created, status_code=201)


@router.post("/operator/tokens/{token_id}/revoke")
def revoke_token(request: Request, token_id: Id, csrf: Text = "") -> Response:
    if (refusal := _refuse_form(request, csrf)) is not None:
        return refusal
    try:
        with state_of(request.app).runtime.session() as session:
            token = accounts.revoke_token(session, ADMIN, token_id)
    except ProblemError as exc:
        return problem_page(request, exc)
    return redirect(request, f"/operator/participants/{token.participant_id}")
