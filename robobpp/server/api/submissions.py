"""Submissions: create (quota checked, then URL checked, rows written in one transaction), status, cancel,
per-episode results. Another participant's submission answers 404, exactly like a missing one."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, Request, Response
from pydantic import TypeAdapter
from sqlalchemy.orm import Session

from robobpp.boards.engine import leaderboard
from robobpp.db import queries, waiting
from robobpp.db.models import Submission
from robobpp.schemas import (
    EpisodeDetail,
    EpisodePublic,
    SubmissionCreate,
    SubmissionPublic,
)
from robobpp.server.api.deps import AdminDep, PrincipalDep, SessionDep, SettingsDep, in_read_session
from robobpp.server.config import Settings
from robobpp.server.problems import ProblemError
from robobpp.server.services import access, admission, verification
from robobpp.server.services.submissions import listed_forms
from robobpp.server.state import state_of
from robobpp.vocabulary import DatasetName, SettingName

router = APIRouter(tags=["submissions"])
#: Ids are bounded so a huge number is a 422, not an integer overflow inside the database.
Id = Annotated[int, Path(ge=1, le=2**31 - 1)]


@router.post(
    "/submissions",
    status_code=201,
    response_model=SubmissionPublic,
    summary="Submit a policy URL for evaluation",
)
async def create_submission(
    request: Request, body: SubmissionCreate, principal: PrincipalDep, settings: SettingsDep
) -> SubmissionPublic:
    state = state_of(request.app)
    return await admission.submit(state.runtime, state.probe_gate, body, principal, settings)


@router.get("/submissions", response_model=list[SubmissionPublic], summary="Your submissions, newest first")
async def list_submissions(
    request: Request,
    principal: PrincipalDep,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0,
) -> Response:
    owner = None if principal.admin else principal.participant_id
    views = state_of(request.app).finished_views

    def listed(session: Session) -> bytes:
        return (
            b"[" + b",".join(listed_forms(views, session, owner, limit, offset, ("api",), _view_json)) + b"]"
        )

    return Response(await in_read_session(request, listed), media_type="application/json")


def _view_json(view: dict[str, Any]) -> bytes:
    return SubmissionPublic.model_validate(view).model_dump_json().encode()


def _json(session: Session, sub: Submission, slots: int, per_worker: int) -> bytes:
    queue = waiting.queue_place(session, sub, slots=slots, per_worker=per_worker)
    return _view_json({**queries.submission_view(session, sub), "queue": queue})


@router.get(
    "/submissions/{submission_id}",
    response_model=SubmissionPublic,
    summary="One submission: status, progress and per-run metrics",
)
async def get_submission(request: Request, submission_id: Id, principal: PrincipalDep) -> Response:
    def one(session: Session) -> bytes:
        sub = access.visible(session, principal, submission_id)
        return state_of(request.app).finished_views.get(
            ("api",),
            sub,
            lambda: _json(
                session,
                sub,
                state_of(request.app).settings.worker_slots,
                state_of(request.app).settings.episodes_per_worker,
            ),
        )

    return Response(await in_read_session(request, one), media_type="application/json")


@router.post(
    "/submissions/{submission_id}/cancel",
    response_model=SubmissionPublic,
    summary="Cancel an evaluation; workers stop taking its episodes",
)
def cancel(submission_id: Id, session: SessionDep, principal: PrincipalDep) -> SubmissionPublic:
    sub = access.cancel(session, principal, submission_id)
    session.refresh(sub)
    return SubmissionPublic.model_validate(queries.submission_view(session, sub))


@router.get(
    "/submissions/{submission_id}/episodes",
    response_model=list[EpisodePublic],
    summary="Per-episode results with termination reasons",
)
async def episodes(request: Request, submission_id: Id, principal: PrincipalDep) -> Response:
    def listed(session: Session) -> bytes:
        sub = access.visible(session, principal, submission_id)
        public = access.seen_by_public(sub, principal)
        return state_of(request.app).finished_views.get(
            ("api-episodes", public),
            sub,
            lambda: _EPISODES.dump_json(
                _EPISODES.validate_python(
                    [access.public_episode(e) if public else e for e in queries.episode_rows(session, sub.id)]
                )
            ),
        )

    return Response(await in_read_session(request, listed), media_type="application/json")


_EPISODES = TypeAdapter(list[EpisodePublic])


@router.get(
    "/submissions/{submission_id}/episodes/{episode_id}",
    response_model=EpisodeDetail,
    summary="One episode; public-track episodes include their replay trace",
)
async def episode(
    request: Request, submission_id: Id, episode_id: Id, principal: PrincipalDep
) -> EpisodeDetail:
    def one(session: Session) -> EpisodeDetail:
        sub = access.visible(session, principal, submission_id)
        ep = queries.get_episode(session, sub.id, episode_id)
        if ep is None:
            raise ProblemError(
                404, "not-found", "Not found", f"no episode {episode_id} in submission {submission_id}"
            )
        trace = ep.trace if sub.track == "public" else None
        summary = queries.episode_summary(ep)
        if access.seen_by_public(sub, principal):
            summary = access.public_episode(summary)
        return EpisodeDetail.model_validate({**summary, "trace": trace})

    return await in_read_session(request, one)


@router.post(
    "/submissions/{submission_id}/verify",
    status_code=201,
    response_model=SubmissionPublic,
    summary="(operator) Re-evaluate a completed private-track submission on the hold-out draw",
)
def verify(
    request: Request, submission_id: Id, principal: AdminDep, settings: SettingsDep
) -> SubmissionPublic:
    """Answers the verification submission (track ``verify``); the original's ``verification`` follows it."""
    with state_of(request.app).runtime.session() as session:  # committed before the answer leaves
        return _verify_one(session, submission_id, settings)


def _verify_one(session: Session, submission_id: int, settings: Settings) -> SubmissionPublic:
    checked = verification.verify_one(session, submission_id, settings.groups)
    session.refresh(checked)
    return SubmissionPublic.model_validate(queries.submission_view(session, checked))


@router.post(
    "/leaderboards/{dataset}/{setting}/verify",
    status_code=201,
    response_model=list[SubmissionPublic],
    summary="(operator) Re-evaluate the board's top entries on the hold-out draw",
)
def verify_top(
    request: Request,
    dataset: DatasetName,
    setting: SettingName,
    principal: AdminDep,
    settings: SettingsDep,
    top: Annotated[int, Query(ge=1, le=50)] = 3,
) -> list[SubmissionPublic]:
    """The ``top`` best-ranked private entries that have no verdict and no verification running yet."""
    with state_of(request.app).runtime.session() as session:  # committed before the answer leaves
        return _verify_top(session, dataset, setting, settings, top)


def _verify_top(
    session: Session, dataset: str, setting: str, settings: Settings, top: int
) -> list[SubmissionPublic]:
    entries = leaderboard(session, dataset, setting).entries[:top]
    started = verification.verify_top(session, entries, settings.groups)
    for sub in started:
        session.refresh(sub)
    return [SubmissionPublic.model_validate(queries.submission_view(session, sub)) for sub in started]
