"""What a new submission must pass before any row is written (docs/server.md): datasets and settings this
server offers, the participant's quota, and the policy URL — a built-in policy (the operator's only), or an
address that is public, reachable and answers ``/info`` under the submission's secret.

:func:`submit` runs them in order — quota before the URL probe, so a participant over quota makes no outbound
call — for both the JSON API and the submit form, which only parse the request and shape the answer.
"""

from __future__ import annotations

from collections.abc import Sequence

from sqlalchemy import select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from robobpp import protocol as P
from robobpp.db import queries, work
from robobpp.db.models import Participant, Submission
from robobpp.policies import BUILTIN
from robobpp.schemas import PULL_URL, SubmissionCreate, SubmissionPublic, clean_name
from robobpp.server.bootstrap import BUILTIN_PARTICIPANT
from robobpp.server.config import Settings
from robobpp.server.principal import Principal
from robobpp.server.probes import ProbeGate
from robobpp.server.problems import ProblemError
from robobpp.server.runtime import Runtime
from robobpp.server.urlsafety import (
    BUILTIN_SCHEME,
    CheckedURL,
    UnsafeURLError,
    check_policy_url,
    probe_policy,
)

#: The problem titles of the URL check's refusals (``UnsafeURLError.kind``).
URL_PROBLEM_TITLES = {
    "policy-url-forbidden": "Policy URL refused",
    "policy-unreachable": "Policy unreachable",
    "policy-signature": "Signature mismatch",
}


def _unique(values: Sequence[str]) -> list[str]:
    return list(dict.fromkeys(values))


def offered(body: SubmissionCreate, settings: Settings) -> tuple[list[str], list[str]]:
    """The submission's datasets and settings (the server's own when it names none), each offered here."""
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
    return datasets, setting_names


def quota_use(session: Session, participant_id: int, settings: Settings) -> dict[str, int]:
    """A participant's quota and its use (``/me`` and the account page)."""
    day, active = queries.quota_usage(session, participant_id)
    return {
        "submissions_today": day,
        "submissions_per_day": settings.quota_submissions_per_day,
        "active": active,
        "concurrent": settings.quota_concurrent,
    }


def check_quota(session: Session, principal: Principal, settings: Settings) -> None:
    """Refuse (429) a participant over quota; the operator has none. Checked before the URL probe, and
    again under the participant's row lock when the submission is written (:func:`create`)."""
    if principal.admin:
        return
    assert principal.participant is not None
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


async def check_policy(
    gate: ProbeGate, body: SubmissionCreate, principal: Principal, settings: Settings
) -> tuple[str, str | None, str]:
    """(policy URL, pinned address, name: ``body.name``, else the policy's ``/info`` label as ``robobpp
    evaluate`` shows it). The only outbound call of the API, made through the probe gate (deadline, size
    cap, bounded concurrency; server/probes.py)."""
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

    def check() -> tuple[CheckedURL, str]:
        # the SDK side, loaded only when a URL is probed (as probe_policy does)
        from robobpp.client.remote import label

        checked = check_policy_url(url, allow_private=settings.allow_private_policy_urls)
        info = probe_policy(
            checked, secret=body.secret, timeout_s=gate.deadline_s, cap_bytes=settings.response_cap_bytes
        )
        return checked, label(P.InfoResponse.model_validate(info))

    try:
        checked, shown = await gate.run(f"participant-{principal.participant_id or 'admin'}", check)
    except UnsafeURLError as exc:
        title = URL_PROBLEM_TITLES.get(exc.kind, "Invalid policy URL")
        raise ProblemError(422, exc.kind, title, exc.detail) from None
    return checked.url, checked.pinned_ip, body.name or clean_name(shown)


def create(
    session: Session,
    principal: Principal,
    body: SubmissionCreate,
    settings: Settings,
    *,
    datasets: list[str],
    setting_names: list[str],
    policy: tuple[str, str | None, str],
) -> Submission:
    """Write the submission (``policy``: what :func:`check_policy` answered). A participant's row is locked
    first, so two concurrent submissions of one participant cannot both pass the quota."""
    if principal.admin:
        participant = session.execute(
            select(Participant).where(Participant.name == BUILTIN_PARTICIPANT)
        ).scalar_one()
    else:
        assert principal.participant is not None
        participant = session.execute(
            select(Participant).where(Participant.id == principal.participant.id).with_for_update()
        ).scalar_one()  # the row lock serialises quota checks of one participant
        check_quota(session, principal, settings)
    url, pinned_ip, name = policy
    return work.create_submission(
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


async def submit(
    runtime: Runtime, gate: ProbeGate, body: SubmissionCreate, principal: Principal, settings: Settings
) -> SubmissionPublic:
    """Admit one submission: offered datasets and settings, the quota, the policy URL, then the rows in one
    transaction. Async on purpose: the policy check awaits the probe gate's own bounded pool and holds none of
    the threads that serve every other route; the short database steps run on that shared pool."""
    datasets, setting_names = offered(body, settings)

    def quota() -> None:
        with runtime.read_session() as session:
            check_quota(session, principal, settings)

    await run_in_threadpool(quota)  # no outbound call over quota
    policy = await check_policy(gate, body, principal, settings)

    def write() -> SubmissionPublic:
        with runtime.session() as session:
            sub = create(
                session,
                principal,
                body,
                settings,
                datasets=datasets,
                setting_names=setting_names,
                policy=policy,
            )
            session.refresh(sub)
            return SubmissionPublic.model_validate(queries.submission_view(session, sub))

    return await run_in_threadpool(write)
