"""Who may see and act on a submission (docs/server.md): its owner and the operator; everyone sees the
built-in baselines, without the simulator's words for how each episode ended. Another participant's
submission answers 404, exactly like a missing one, so ids reveal nothing."""

from __future__ import annotations

from sqlalchemy.orm import Session

from robobpp.db import work
from robobpp.db.models import Submission
from robobpp.db.queries import EpisodeSummary
from robobpp.server.principal import Principal
from robobpp.server.problems import ProblemError


def is_owner(sub: Submission, *, admin: bool, participant_id: int | None) -> bool:
    """May the caller see this submission's details, live status and failure reasons (the API's token and
    the pages' session alike)?"""
    return admin or (participant_id is not None and sub.participant_id == participant_id)


def may_see(sub: Submission, *, admin: bool, participant_id: int | None) -> bool:
    """Its owner and the operator see a submission; everyone sees the baselines."""
    return is_owner(sub, admin=admin, participant_id=participant_id) or sub.participant.is_builtin


def visible(session: Session, principal: Principal, submission_id: int) -> Submission:
    """The submission if ``principal`` may see it (404 otherwise)."""
    sub = session.get(Submission, submission_id)
    if sub is not None and may_see(sub, admin=principal.admin, participant_id=principal.participant_id):
        return sub
    raise ProblemError(404, "not-found", "Not found", f"no submission {submission_id} visible to this token")


def cancel(session: Session, principal: Principal, submission_id: int) -> Submission:
    """Cancel an evaluation of the caller's (any, for the operator); 409 when it has finished. A baseline is
    the operator's, and so is a verification: its participant must not erase its own verdict."""
    sub = visible(session, principal, submission_id)
    if sub.participant.is_builtin and not principal.admin:
        raise ProblemError(
            404, "not-found", "Not found", f"no submission {submission_id} visible to this token"
        )
    if sub.track == "verify" and not principal.admin:
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
    return sub


def seen_by_public(sub: Submission, principal: Principal) -> bool:
    """A baseline's episodes as every participant sees them (not its owner: the operator)."""
    return not is_owner(sub, admin=principal.admin, participant_id=principal.participant_id)


def public_episode(summary: EpisodeSummary) -> EpisodeSummary:
    """How an episode ended, without the simulator's words: a private-track detail ("box top at Z cm") is a
    number per test episode, and the pages never showed it to anyone but the owner either."""
    return {**summary, "termination_detail": ""}
