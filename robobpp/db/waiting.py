"""Where a queued submission stands: its place in the fair-share order and an estimate of its start.

The claim order (:func:`robobpp.db.work.fair_key`) is dynamic — each claim raises its participant's running
count — so the place is not a rank in a sorted list: it is how many claims other participants make before
this submission's first one, each rising to the level this participant's own claim reaches (fewest running
first; at the same level, the one that started longest ago first). It assumes nothing finishes meanwhile
(finishes free slots; they never move a waiting participant back), so the place is an upper bound. The
estimate turns it into time with the pool's size — the episodes running now, since a submission waits only
while every slot is busy — and the mean duration of the last finished episodes. Nothing here reads the
pending backlog row by row: queued submissions count by their ``episodes_total``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from robobpp.db.models import EpisodeRow, Participant, Submission, utcnow
from robobpp.db.work import fair_key, is_baseline, participant_loads

#: Finished episodes whose mean duration makes the estimate (recent ones: the load of today, not last year).
RECENT_EPISODES = 100
#: ...found among this many newest episode rows.
RECENT_WINDOW = 20_000


def queue_place(session: Session, sub: Submission, now: datetime | None = None) -> dict[str, Any] | None:
    """``{"position", "ahead", "running", "estimated_start_s", "estimated_start"}`` of a queued submission
    (``None`` otherwise): ``position`` 1 is the next claim; the estimate is ``None`` until some episode has
    finished (nothing to measure)."""
    if sub.status != "queued":
        return None
    now = now or utcnow()
    loads = {load.participant_id: load for load in participant_loads(session)}
    mine = loads.get(sub.participant_id)
    if mine is None:  # cannot happen for a queued submission; a race with its cancel
        return None
    running_pending = _running_pending(session)
    pending = _pending(session, running_pending)
    # This participant's own episodes ahead of this submission's first: those of its active submissions that
    # the claim takes first (older ones; on the built-in participant the operator's before the baselines'):
    # the running ones' pending episodes and the queued ones' whole size.
    own_before = _own_before(session, sub)
    level = mine.running + own_before  # this participant's running count when its claim for this one comes
    ahead = own_before
    for pid, load in loads.items():
        if pid == sub.participant_id or not pending.get(pid):
            continue
        if load.builtin != mine.builtin:
            ahead += pending[pid] if mine.builtin else 0  # participants' work before the baselines'
            continue
        first = fair_key(load)[2:] < fair_key(mine)[2:]  # at the same level, who claims first
        ahead += min(pending[pid], max(0, level - load.running + (1 if first else 0)))
    running = sum(load.running for load in loads.values())
    pool = max(1, running)
    free = max(0, pool - running)
    mean_s = _mean_episode_s(session)
    estimate = None
    if mean_s is not None:
        estimate = round(max(0, math.ceil((ahead + 1 - free) / pool)) * mean_s, 1)
    return {
        "position": ahead + 1,
        "ahead": ahead,
        "running": running,
        "estimated_start_s": estimate,
        "estimated_start": None if estimate is None else now + timedelta(seconds=estimate),
    }


def _own_before(session: Session, sub: Submission) -> int:
    """Episodes of ``sub``'s participant that the claim takes before ``sub``'s first
    (:func:`robobpp.db.work.submission_order`)."""
    mine = (is_baseline(sub.policy_url), sub.id)
    before: list[int] = []
    queued = 0
    for sid, url, status, total in session.execute(
        select(Submission.id, Submission.policy_url, Submission.status, Submission.episodes_total).where(
            Submission.participant_id == sub.participant_id,
            Submission.status.in_(("queued", "running")),
            Submission.id != sub.id,
        )
    ):
        if (is_baseline(url), sid) > mine:
            continue
        if status == "queued":
            queued += int(total or 0)
        else:
            before.append(sid)
    if not before:
        return queued
    running = session.execute(
        select(func.count()).where(EpisodeRow.submission_id.in_(before), EpisodeRow.status == "pending")
    ).scalar_one()
    return queued + int(running)


def _pending(session: Session, running_pending: dict[int, int]) -> dict[int, int]:
    """Pending episodes per participant: queued submissions by their size, running ones by the index."""
    out: dict[int, int] = {}
    for pid, n in session.execute(
        select(Submission.participant_id, func.sum(Submission.episodes_total))
        .where(Submission.status == "queued")
        .group_by(Submission.participant_id)
    ):
        out[pid] = out.get(pid, 0) + int(n or 0)
    for pid, n in running_pending.items():
        out[pid] = out.get(pid, 0) + n
    return out


def _running_pending(session: Session) -> dict[int, int]:
    """Pending episodes of running submissions per participant. The running submissions are listed first and
    their episodes counted by id (the (submission, status) index): a join let SQLite scan every pending
    episode of the backlog instead."""
    owners: dict[int, int] = {
        sid: pid
        for sid, pid in session.execute(
            select(Submission.id, Submission.participant_id).where(Submission.status == "running")
        )
    }
    out: dict[int, int] = {}
    if owners:
        for sid, n in session.execute(
            select(EpisodeRow.submission_id, func.count())
            .where(EpisodeRow.submission_id.in_(list(owners)), EpisodeRow.status == "pending")
            .group_by(EpisodeRow.submission_id)
        ):
            out[owners[sid]] = out.get(owners[sid], 0) + int(n)
    return out


def _mean_episode_s(session: Session) -> float | None:
    """Mean duration of the last finished episodes among the newest :data:`RECENT_WINDOW` rows (a primary-key
    range: the cost is the same with 2.7 M finished episodes as with none finished)."""
    newest = session.execute(select(func.max(EpisodeRow.id))).scalar_one()
    if newest is None:
        return None
    recent = (
        select(EpisodeRow.started_at, EpisodeRow.finished_at)
        .where(
            EpisodeRow.id > newest - RECENT_WINDOW,
            EpisodeRow.status == "done",
            EpisodeRow.started_at.is_not(None),
            EpisodeRow.finished_at.is_not(None),
        )
        .order_by(EpisodeRow.id.desc())
        .limit(RECENT_EPISODES)
    )
    # the statement leaves out unset times; the check says so to the type checker
    spans = [(f - s).total_seconds() for s, f in session.execute(recent) if s is not None and f is not None]
    return sum(spans) / len(spans) if spans else None


@dataclass(frozen=True, slots=True)
class Backlog:
    """The work the service has not finished: what the log reports every minute and the home page shows."""

    queued: int
    running: int
    #: Episodes still to run: the queued submissions' and the running ones' pending, waiting and running ones.
    episodes_left: int
    episodes_running: int
    #: The built-in participant's (the baselines') submissions, each baseline's latest per track, by status.
    baselines: dict[str, int]
    #: Mean duration of the last finished episodes (None: none finished yet).
    mean_episode_s: float | None
    #: Seconds until the last episode ends at that mean on ``workers`` slots (None: nothing measured yet).
    expected_s: float | None
    expected_end: datetime | None


def backlog(session: Session, workers: int, now: datetime | None = None) -> Backlog | None:
    """The unfinished work (``None`` when every submission has finished), and when it should end with
    ``workers`` episodes running at once. Reads the active submissions and their episodes by the (submission,
    status) index, never the backlog row by row: queued submissions count by their ``episodes_total``."""
    now = now or utcnow()
    active = session.execute(
        select(Submission.id, Submission.status, Submission.episodes_total).where(
            Submission.status.in_(("queued", "running"))
        )
    ).all()
    if not active:
        return None
    queued = [total for _, status, total in active if status == "queued"]
    running_ids = [sid for sid, status, _ in active if status == "running"]
    left = sum(queued)
    episodes_running = 0
    if running_ids:
        for status, n in session.execute(
            select(EpisodeRow.status, func.count())
            .where(
                EpisodeRow.submission_id.in_(running_ids),
                EpisodeRow.status.in_(("pending", "waiting", "running")),
            )
            .group_by(EpisodeRow.status)
        ):
            left += int(n)
            if status == "running":
                episodes_running = int(n)
    latest: dict[tuple[str, str], str] = {}
    for url, track, status in session.execute(
        select(Submission.policy_url, Submission.track, Submission.status)
        .join(Participant, Participant.id == Submission.participant_id)
        .where(Participant.is_builtin.is_(True), Submission.policy_url.startswith("builtin:"))
        .order_by(Submission.id)
    ):
        latest[(url, track)] = status
    baselines: dict[str, int] = {}
    for status in latest.values():
        baselines[status] = baselines.get(status, 0) + 1
    mean_s = _mean_episode_s(session)
    expected = None
    if mean_s is not None:
        expected = round(math.ceil(left / max(1, workers)) * mean_s, 1)
    return Backlog(
        queued=len(queued),
        running=len(running_ids),
        episodes_left=left,
        episodes_running=episodes_running,
        baselines=baselines,
        mean_episode_s=mean_s,
        expected_s=expected,
        expected_end=None if expected is None else now + timedelta(seconds=expected),
    )
