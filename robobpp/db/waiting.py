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
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from robobpp.db.models import EpisodeRow, Submission, utcnow
from robobpp.db.work import fair_key, participant_loads

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
    # This participant's own episodes ahead of this submission's first: its running submissions' pending ones
    # and its older queued submissions'.
    own_before = int(
        session.execute(
            select(func.coalesce(func.sum(Submission.episodes_total), 0)).where(
                Submission.participant_id == sub.participant_id,
                Submission.status == "queued",
                Submission.id < sub.id,
            )
        ).scalar_one()
    ) + running_pending.get(sub.participant_id, 0)
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
