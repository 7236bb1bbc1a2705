"""Where a queued submission stands: its place in the fair-share order and an estimate of its start.

The claim order (:func:`robobpp.db.work.claim_episode`) is dynamic — each claim raises its participant's
running count — so the place is found by replaying that order over the participants' waiting work, not by
sorting episodes once. It assumes nothing finishes meanwhile (finishes free slots; they never move a waiting
participant back), so the place is an upper bound. The estimate turns it into time with the pool's size —
the episodes running now, since a submission waits only while every slot is busy — and the mean duration
of the last finished episodes.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from robobpp.db.models import EpisodeRow, Participant, Submission, utcnow
from robobpp.db.work import ACTIVE_SUBMISSION

#: Finished episodes whose mean duration makes the estimate (recent ones: the load of today, not last year).
RECENT_EPISODES = 100
#: Claims replayed at most (a place beyond is shown as "more than").
MAX_REPLAY = 100_000


@dataclass(slots=True)
class _Waiting:
    builtin: bool
    running: int
    last_start: float  # seconds since the epoch; -inf: never started (such a participant goes first)
    first_pending: int
    pending: int

    def key(self) -> tuple[Any, ...]:
        return (self.builtin, self.running, self.last_start, self.first_pending)


def queue_place(session: Session, sub: Submission, now: datetime | None = None) -> dict[str, Any] | None:
    """``{"position", "ahead", "running", "estimated_start_s", "estimated_start"}`` of a queued submission
    (``None`` otherwise): ``position`` 1 is the next claim; the estimate is ``None`` until some episode has
    finished (nothing to measure)."""
    if sub.status != "queued":
        return None
    now = now or utcnow()
    load = session.execute(
        select(
            Submission.participant_id,
            Participant.is_builtin,
            func.count().filter(EpisodeRow.status == "running"),
            func.count().filter(EpisodeRow.status == "pending"),
            func.max(EpisodeRow.started_at),
            func.min(EpisodeRow.id).filter(EpisodeRow.status == "pending"),
        )
        .join(EpisodeRow, EpisodeRow.submission_id == Submission.id)
        .join(Participant, Participant.id == Submission.participant_id)
        .where(Submission.status.in_(ACTIVE_SUBMISSION))
        .group_by(Submission.participant_id, Participant.is_builtin)
    ).all()
    first_own = session.execute(
        select(func.min(EpisodeRow.id)).where(EpisodeRow.submission_id == sub.id)
    ).scalar_one()
    # The participant's own older episodes come before this submission's first one (oldest first within it).
    own_before = session.execute(
        select(func.count())
        .select_from(EpisodeRow)
        .join(Submission, Submission.id == EpisodeRow.submission_id)
        .where(Submission.participant_id == sub.participant_id, EpisodeRow.status == "pending",
               Submission.status.in_(ACTIVE_SUBMISSION), EpisodeRow.id < first_own)
    ).scalar_one()  # fmt: skip
    waiting: dict[int, _Waiting] = {}
    total_running = 0
    for pid, builtin, running, pending, last_start, first_pending in load:
        total_running += running
        if pending:
            started = last_start.timestamp() if last_start is not None else -math.inf
            waiting[pid] = _Waiting(bool(builtin), running, started, first_pending, pending)
    ahead = _claims_before(waiting, sub.participant_id, own_before + 1, now.timestamp())
    pool = max(1, total_running)
    free = max(0, pool - total_running)
    mean_s = _mean_episode_s(session)
    estimate = None
    if ahead is not None and mean_s is not None:
        rounds = max(0, math.ceil((ahead + 1 - free) / pool))
        estimate = round(rounds * mean_s, 1)
    return {
        "position": None if ahead is None else ahead + 1,
        "ahead": ahead,
        "running": total_running,
        "estimated_start_s": estimate,
        "estimated_start": None if estimate is None else now + timedelta(seconds=estimate),
    }


def _claims_before(waiting: dict[int, _Waiting], participant: int, needed: int, now: float) -> int | None:
    """Replay the fair order until ``participant`` has made ``needed`` claims; the claims made before."""
    heap = [(w.key(), pid) for pid, w in waiting.items()]
    heapq.heapify(heap)
    made = 0
    tick = 0
    while heap and made < MAX_REPLAY:
        _key, pid = heapq.heappop(heap)
        w = waiting[pid]
        if pid == participant:
            needed -= 1
            if needed == 0:
                return made
        made += 1
        tick += 1
        w.running += 1
        w.pending -= 1
        w.last_start = now + tick * 1e-3  # later than every start so far: round-robin among equals
        if w.pending:
            heapq.heappush(heap, (w.key(), pid))
    return None if made >= MAX_REPLAY else made


def _mean_episode_s(session: Session) -> float | None:
    recent = (
        select(EpisodeRow.started_at, EpisodeRow.finished_at)
        .where(
            EpisodeRow.status == "done",
            EpisodeRow.started_at.is_not(None),
            EpisodeRow.finished_at.is_not(None),
        )
        .order_by(EpisodeRow.id.desc())
        .limit(RECENT_EPISODES)
    )
    spans = [(f - s).total_seconds() for s, f in session.execute(recent)]
    return sum(spans) / len(spans) if spans else None
