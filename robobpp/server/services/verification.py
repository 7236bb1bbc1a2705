"""Verification on the hold-out draw, started by the operator (docs/server.md, "Hostile participants and the threat model of the private
split"): which submissions may be re-evaluated, and the verification submission itself. Its verdict is
written when it finishes (:mod:`robobpp.db.verification`, called as the run completes in db/work.py)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from sqlalchemy.orm import Session

from robobpp.db import work
from robobpp.db.models import Submission
from robobpp.server.problems import ProblemError

#: Verdicts that stand (or are being reached): the board's top entries with one are not started again
#: (``unverifiable``: the participant's policy could not be reached during the re-run, db/verification.py).
SETTLED = ("running", "verified", "disagrees", "unverifiable")


def start_verification(session: Session, original: Submission, groups: int) -> Submission:
    """Queue the re-evaluation of ``original`` on the hold-out draw; the original shows it as running.

    It runs in the original's mode: a pull submission's verification is a pull submission too, served when
    the participant's client joins it (``robobpp connect --submission ID``); as a push job its URL would be
    the placeholder ``pull:`` and every episode would fail."""
    verify = work.create_submission(
        session,
        original.participant,
        name=original.name[:80],
        policy_url=original.policy_url,
        secret=original.secret,
        pinned_ip=original.pinned_ip,
        datasets=list(original.datasets),
        settings=list(original.settings),
        groups=groups,
        track="verify",
        lookahead=original.lookahead,
        mode=original.mode,
    )
    verify.verifies_id = original.id
    original.verification = {"status": "running", "submission_id": verify.id}
    session.flush()
    return verify


def verify_one(session: Session, submission_id: int, groups: int) -> Submission:
    """Start verifying one completed private-track submission (404 when missing, 409 when it cannot be)."""
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
    return start_verification(session, original, groups)


def verify_top(session: Session, entries: Iterable[Mapping[str, Any]], groups: int) -> list[Submission]:
    """Start verifying the given board entries (best first) that have no verdict and none running."""
    started = []
    for entry in entries:
        original = session.get(Submission, entry["submission_id"])
        if original is None or (original.verification or {}).get("status") in SETTLED:
            continue
        started.append(start_verification(session, original, groups))
    return started
