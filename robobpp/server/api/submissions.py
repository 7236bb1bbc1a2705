"""Submissions: create (quota checked, then URL checked, rows written in one transaction), status, cancel,
per-episode results. Another participant's submission answers 404, exactly like a missing one."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from typing import Annotated, Any, TypeVar

from fastapi import APIRouter, Path, Query, Request, Response
from pydantic import TypeAdapter
from sqlalchemy import select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from robobpp import protocol as P
from robobpp.db import queries, waiting, work
from robobpp.db.models import Participant, Submission
from robobpp.policies import BUILTIN
from robobpp.schemas import (
    PULL_URL,
    DatasetName,
    EpisodeDetail,
    EpisodePublic,
    SettingName,
    SubmissionCreate,
    SubmissionPublic,
    clean_name,
)
from robobpp.server.api.deps import (
    AdminDep,
    Principal,
    PrincipalDep,
    SessionDep,
    SettingsDep,
    in_read_session,
)
from robobpp.server.bootstrap import BUILTIN_PARTICIPANT
from robobpp.server.config import Settings
from robobpp.server.probes import ProbeGate
from robobpp.server.problems import ProblemError
from robobpp.server.services.board_engine import leaderboard
from robobpp.server.services.submissions import FinishedViews, finished_views
from robobpp.server.urlsafety import (
    BUILTIN_SCHEME,
    CheckedURL,
    UnsafeURLError,
    check_policy_url,
    probe_policy,
)

router = APIRouter(tags=["submissions"])
T = TypeVar("T")
#: Ids are bounded so a huge number is a 422, not an integer overflow inside the database.
Id = Annotated[int, Path(ge=1, le=2**31 - 1)]


def _unique(values: Sequence[str]) -> list[str]:
    return list(dict.fromkeys(values))


def _visible(session: SessionDep, principal: PrincipalDep, submission_id: int) -> Submission:
    sub = session.get(Submission, submission_id)
    if sub is not None and (
        principal.admin or sub.participant_id == principal.participant_id or sub.participant.is_builtin
    ):
        return sub
    raise ProblemError(404, "not-found", "Not found", f"no submission {submission_id} visible to this token")


async def _check_url(
    request: Request, body: SubmissionCreate, principal: Principal, settings: Settings
) -> tuple[str, str | None, str]:
    """(policy URL, pinned address, name: ``body.name``, else the policy's ``/info`` label as ``robobpp
    evaluate`` shows it). Runs before any row is written; the only outbound call of the API, made through
    the probe gate (deadline, size cap, bounded concurrency; server/probes.py)."""
    if body.mode == "pull":  # nothing to reach: the participant's client connects to us
        return PULL_URL, None, body.name or "pull"
    assert body.policy_url is not None  # the schema demands it in push mode
    url = body.policy_url.strip()
    if url.startswith(BUILTIN_SCHEME):
        if not principal.admin:
            raise ProblemError(
                422,
                "policy-url-invalid",
                "Invalid policy URL",
                "built-in policies are submitted by the operator only",
            )
        if url[len(BUILTIN_SCHEME) :] not in BUILTIN:
            raise ProblemError(
                422, "policy-url-invalid", "Invalid policy URL", f"unknown built-in policy {url!r}"
            )
        return url, None, body.name or clean_name(url[len(BUILTIN_SCHEME) :])
    gate: ProbeGate = request.app.state.probe_gate

    def check() -> tuple[CheckedURL, str]:
        # the SDK side, loaded only by the route (as probe_policy does)
        from robobpp.client.remote import label

        checked = check_policy_url(url, allow_private=settings.allow_private_policy_urls)
        info = probe_policy(
            checked, secret=body.secret, timeout_s=gate.deadline_s, cap_bytes=settings.response_cap_bytes
        )
        return checked, label(P.InfoResponse.model_validate(info))

    try:
        checked, shown = await gate.run(f"participant-{principal.participant_id or 'admin'}", check)
    except UnsafeURLError as exc:
        title = {
            "policy-url-forbidden": "Policy URL refused",
            "policy-unreachable": "Policy unreachable",
            "policy-signature": "Signature mismatch",
        }
        raise ProblemError(422, exc.kind, title.get(exc.kind, "Invalid policy URL"), exc.detail) from None
    return checked.url, checked.pinned_ip, body.name or clean_name(shown)


def _check_quota(
    request: Request, principal: Principal, settings: Settings, *, lock: Session | None = None
) -> None:
    """Refuse (429) a participant over quota. Called before the probe, and again under the row lock."""
    if principal.admin:
        return
    assert principal.participant is not None
    with contextlib.ExitStack() as stack:
        session = lock if lock is not None else stack.enter_context(request.app.state.runtime.read_session())
        day, active = queries.quota_usage(session, principal.participant.id)
    if day >= settings.quota_submissions_per_day:
        raise ProblemError(
            429,
            "quota-exceeded",
            "Quota exceeded",
            f"at most {settings.quota_submissions_per_day} submissions per 24 hours",
        )
    if active >= settings.quota_concurrent:
        raise ProblemError(
            429,
            "quota-exceeded",
            "Quota exceeded",
            f"at most {settings.quota_concurrent} evaluations at a time; wait or cancel one",
        )


@router.post(
    "/submissions",
    status_code=201,
    response_model=SubmissionPublic,
    summary="Submit a policy URL for evaluation",
)
async def create_submission(
    request: Request, body: SubmissionCreate, principal: PrincipalDep, settings: SettingsDep
) -> SubmissionPublic:
    # async on purpose: the policy check awaits its own bounded pool and holds none of the threads that
    # serve every other route; the short database steps run on that shared pool.
    datasets = _unique(body.datasets or list(settings.datasets))
    setting_names = _unique(body.settings or list(settings.enabled_settings))
    for d in datasets:
        if d not in settings.datasets:
            raise ProblemError(
                422, "dataset-unavailable", "Dataset unavailable", f"dataset {d!r} is not offered"
            )
    for s in setting_names:
        if s not in settings.enabled_settings:
            raise ProblemError(
                422,
                "setting-unavailable",
                "Setting unavailable",
                f"setting {s!r} is not offered here (offered: {', '.join(settings.enabled_settings)})",
            )
    await run_in_threadpool(_check_quota, request, principal, settings)  # no outbound call over quota
    url, pinned_ip, name = await _check_url(request, body, principal, settings)

    def create() -> SubmissionPublic:
        with request.app.state.runtime.session() as session:
            if principal.admin:
                participant = session.execute(
                    select(Participant).where(Participant.name == BUILTIN_PARTICIPANT)
                ).scalar_one()
            else:
                assert principal.participant is not None
                participant = session.execute(
                    select(Participant).where(Participant.id == principal.participant.id).with_for_update()
                ).scalar_one()  # the row lock serialises quota checks of one participant
                _check_quota(request, principal, settings, lock=session)
            sub = work.create_submission(
                session,
                participant,
                name=name,
                policy_url=url,
                secret=body.secret,
                pinned_ip=pinned_ip,
                datasets=datasets,
                settings=setting_names,
                groups=settings.groups,
                track=body.track,
                lookahead=body.lookahead,
                mode=body.mode,
            )
            session.refresh(sub)
            return SubmissionPublic.model_validate(queries.submission_view(session, sub))

    return await run_in_threadpool(create)


@router.get("/submissions", response_model=list[SubmissionPublic], summary="Your submissions, newest first")
async def list_submissions(
    request: Request,
    principal: PrincipalDep,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0,
) -> Response:
    owner = None if principal.admin else principal.participant_id
    views = finished_views(request.app.state)

    def listed(session: Session) -> bytes:
        return (
            b"[" + b",".join(listed_forms(views, session, owner, limit, offset, ("api",), _view_json)) + b"]"
        )

    return Response(await in_read_session(request, listed), media_type="application/json")


def listed_forms(
    views: FinishedViews,
    session: Session,
    owner: int | None,
    limit: int,
    offset: int,
    kind: tuple[Any, ...],
    build: Callable[[dict[str, Any]], T],
) -> list[T]:
    """A page of submissions (newest first; ``owner``'s, or everyone's) as served forms, each ``build``
    from its :func:`queries.submission_view` and kept in ``views`` under ``kind``.

    The page's keys first (a few columns, no objects) and the episode counts of those not finished (one
    aggregate): what tells whether a form built before is still current. Only the submissions without one
    are then read whole, with their runs and progress (one query each, not two per submission)."""
    keys = queries.list_submission_keys(session, owner, limit=limit, offset=offset)
    counts = queries.waiting_counts(session, keys)

    def build_missing(missing: list[int]) -> list[T]:
        subs = queries.submissions_by_id(session, missing)
        progress = queries.submissions_progress(session, missing, counts)
        runs = queries.runs_of(session, missing)
        return [
            build(queries.submission_view(session, subs[i], progress.get(i), runs.get(i))) for i in missing
        ]

    return views.get_many(kind, keys, build_missing, counts)


def submission_models(
    views: FinishedViews, session: Session, principal: Principal, limit: int = 50, offset: int = 0
) -> list[SubmissionPublic]:
    """The listed submissions as models (the account pages); see :func:`listed_forms`."""
    owner = None if principal.admin else principal.participant_id
    return listed_forms(views, session, owner, limit, offset, ("model",), SubmissionPublic.model_validate)


def _view_json(view: dict[str, Any]) -> bytes:
    return SubmissionPublic.model_validate(view).model_dump_json().encode()


def _json(session: Session, sub: Submission) -> bytes:
    return _view_json({**queries.submission_view(session, sub), "queue": waiting.queue_place(session, sub)})


@router.get(
    "/submissions/{submission_id}",
    response_model=SubmissionPublic,
    summary="One submission: status, progress and per-run metrics",
)
async def get_submission(request: Request, submission_id: Id, principal: PrincipalDep) -> Response:
    def one(session: Session) -> bytes:
        sub = _visible(session, principal, submission_id)
        return finished_views(request.app.state).get(("api",), sub, lambda: _json(session, sub))

    return Response(await in_read_session(request, one), media_type="application/json")


@router.post(
    "/submissions/{submission_id}/cancel",
    response_model=SubmissionPublic,
    summary="Cancel an evaluation; workers stop taking its episodes",
)
def cancel(submission_id: Id, session: SessionDep, principal: PrincipalDep) -> SubmissionPublic:
    sub = _visible(session, principal, submission_id)
    if sub.participant.is_builtin and not principal.admin:
        raise ProblemError(
            404, "not-found", "Not found", f"no submission {submission_id} visible to this token"
        )
    if sub.track == "verify" and not principal.admin:  # its participant must not erase its own verdict
        raise ProblemError(
            403,
            "forbidden",
            "The operator's verification",
            f"submission {submission_id} re-evaluates your entry on the hold-out draw; only the "
            "operator can cancel it",
        )
    if not work.cancel_submission(session, sub):
        raise ProblemError(409, "conflict", "Already finished", f"submission {submission_id} is {sub.status}")
    session.flush()
    session.refresh(sub)
    return SubmissionPublic.model_validate(queries.submission_view(session, sub))


@router.get(
    "/submissions/{submission_id}/episodes",
    response_model=list[EpisodePublic],
    summary="Per-episode results with termination reasons",
)
async def episodes(request: Request, submission_id: Id, principal: PrincipalDep) -> Response:
    def listed(session: Session) -> bytes:
        sub = _visible(session, principal, submission_id)
        public = _seen_by_public(sub, principal)
        return finished_views(request.app.state).get(
            ("api-episodes", public),
            sub,
            lambda: _EPISODES.dump_json(
                _EPISODES.validate_python(
                    [_public_episode(e) if public else e for e in queries.episode_rows(session, sub.id)]
                )
            ),
        )

    return Response(await in_read_session(request, listed), media_type="application/json")


_EPISODES = TypeAdapter(list[EpisodePublic])


def _seen_by_public(sub: Submission, principal: Principal) -> bool:
    """A baseline's episodes as every participant sees them (not its owner: the operator)."""
    return not principal.admin and sub.participant_id != principal.participant_id


def _public_episode(summary: dict[str, Any]) -> dict[str, Any]:
    """How an episode ended, without the simulator's words: a private-track detail ("box top at Z cm") is a
    number per test episode, and the pages never showed it to anyone but the owner either."""
    return {**summary, "termination_detail": ""}


@router.get(
    "/submissions/{submission_id}/episodes/{episode_id}",
    response_model=EpisodeDetail,
    summary="One episode; public-track episodes include their replay trace",
)
async def episode(
    request: Request, submission_id: Id, episode_id: Id, principal: PrincipalDep
) -> EpisodeDetail:
    def one(session: Session) -> EpisodeDetail:
        sub = _visible(session, principal, submission_id)
        ep = queries.get_episode(session, sub.id, episode_id)
        if ep is None:
            raise ProblemError(
                404, "not-found", "Not found", f"no episode {episode_id} in submission {submission_id}"
            )
        trace = ep.trace if sub.track == "public" else None
        summary = queries.episode_summary(ep)
        if _seen_by_public(sub, principal):
            summary = _public_episode(summary)
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
    with request.app.state.runtime.session() as session:  # committed before the answer leaves
        return _verify_one(session, submission_id, settings)


def _verify_one(session: Session, submission_id: int, settings: Settings) -> SubmissionPublic:
    from robobpp.db.verification import start_verification

    original = session.get(Submission, submission_id)
    if original is None:
        raise ProblemError(404, "not-found", "Not found", f"no submission {submission_id}")
    if original.track != "private" or original.status != "completed":
        raise ProblemError(
            409,
            "conflict",
            "Cannot verify",
            f"only completed private-track submissions are verified (this one: {original.track}, {original.status})",
        )
    running = original.verification or {}
    if running.get("status") == "running":
        raise ProblemError(
            409,
            "conflict",
            "Already verifying",
            f"verification #{running['submission_id']} is still running",
        )
    checked = start_verification(session, original, settings.groups)
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
    with request.app.state.runtime.session() as session:  # committed before the answer leaves
        return _verify_top(session, dataset, setting, settings, top)


def _verify_top(
    session: Session, dataset: str, setting: str, settings: Settings, top: int
) -> list[SubmissionPublic]:
    from robobpp.db.verification import start_verification

    started = []
    for entry in leaderboard(session, dataset, setting)["entries"][:top]:
        original = session.get(Submission, entry["submission_id"])
        if original is None or (original.verification or {}).get("status") in (
            "running",
            "verified",
            "disagrees",
        ):
            continue
        started.append(start_verification(session, original, settings.groups))
    for sub in started:
        session.refresh(sub)
    return [SubmissionPublic.model_validate(queries.submission_view(session, sub)) for sub in started]
