"""Where a queued submission stands: its place in the fair-share order and an estimate of its start.

The claim order (:func:`robobpp.db.work.fair_key`) is dynamic — each claim raises its participant's running
count — so the place is not a rank in a sorted list: it is how many claims other participants make before
this submission's first one, each rising to the level this participant's own claim reaches (fewest running
first; at the same level, the one that started longest ago first). It assumes nothing finishes meanwhile
(finishes free slots; they never move a waiting participant back), so the place is an upper bound.

The estimate turns the place into time (docs/server.md, "Where a queued submission stands"): each running
episode frees its slot after its expected remaining time, and the episodes ahead take the slots as they free,
each holding one for its submission's expected episode time; this submission starts when the next slot frees
after them. An episode's expected time is, the first known of: the mean of its submission's finished episodes;
its policy's observed time per box times the episode's boxes; the recent mean of finished episodes of its
setting (of any setting when that has none). Nothing here reads the pending backlog row by row: queued
submissions count by their ``episodes_total``.
"""

from __future__ import annotations

import heapq
import itertools
import math
import statistics
from collections import defaultdict
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from robobpp.db.models import EpisodeRow, Participant, Submission, utcnow
from robobpp.db.work import fair_key, is_baseline, participant_loads
from robobpp.vocabulary import ACTIVE_SUBMISSION

#: Finished episodes whose mean duration is a setting's typical episode time (recent ones: the load of today).
RECENT_EPISODES = 100
#: ...found among this many newest episode rows.
RECENT_WINDOW = 20_000
#: A submission's own finished episodes whose mean is its expected episode time (its newest ones).
OWN_EPISODES = 20
#: Episodes ahead placed one by one on the slots; any beyond are spread evenly over the pool.
SIMULATED = 10_000


@dataclass(frozen=True, slots=True)
class Running:
    """A running episode as the estimate sees it."""

    submission_id: int
    setting: str
    elapsed_s: float
    #: Boxes handled so far (the heartbeat's figure) and in all (``None`` until its first heartbeat).
    step: int
    boxes_total: int | None
    #: A built-in policy's episode: it computes on the worker all along, so it holds a whole worker.
    builtin: bool = False

    @property
    def paced_s(self) -> float | None:
        """Its whole time at the pace its policy has kept so far (``None`` before the first box)."""
        if self.step <= 0 or not self.boxes_total:
            return None
        return self.elapsed_s / self.step * max(self.boxes_total, self.step)


def queue_place(
    session: Session, sub: Submission, now: datetime | None = None, *, slots: int = 0, per_worker: int = 1
) -> dict[str, Any] | None:
    """``{"position", "ahead", "running", "estimated_start_s", "estimated_start"}`` of a queued submission
    (``None`` otherwise): ``position`` 1 is the next claim. ``slots`` is the evaluation pool's size when known
    (the local workers; 0: the running episodes are taken for it); ``per_worker`` the episodes a worker keeps
    in flight while they wait on their policies (robobpp/worker/multiplex.py): a participant's episode takes
    one of a worker's ``per_worker`` places, a built-in's the whole worker (it computes all along). The
    estimate is ``None`` while some episode's time cannot be told (no episode finished anywhere and no policy
    past its first box)."""
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
    ahead_of = {sub.participant_id: own_before}  # episodes each participant claims before this one's first
    for pid, load in loads.items():
        if pid == sub.participant_id or not pending.get(pid):
            continue
        if load.builtin != mine.builtin:
            ahead_of[pid] = pending[pid] if mine.builtin else 0  # participants' work before the baselines'
            continue
        first = fair_key(load)[2:] < fair_key(mine)[2:]  # at the same level, who claims first
        ahead_of[pid] = min(pending[pid], max(0, level - load.running + (1 if first else 0)))
    ahead = sum(ahead_of.values())
    running = sum(load.running for load in loads.values())
    # the episodes ahead come from each participant's oldest active submission (which the claim takes first)
    first_of = {pid: loads[pid].first_submission for pid, n in ahead_of.items() if n}
    times = EpisodeTimes(session, now, first_of.values())

    work = [
        (times.of_submission(first_of[pid]), ahead_of[pid] * places(loads[pid].builtin, per_worker))
        for pid in first_of
    ]
    remaining = [t for e in times.running for t in [times.remaining(e)] * places(e.builtin, per_worker)]
    estimate = None
    if all(t is not None for t in remaining) and all(t is not None for t, _ in work):
        start = start_after(
            [t for t in remaining if t is not None],
            max(slots * per_worker, len(remaining), 1),
            [(t, n) for t, n in work if t is not None],
        )
        estimate = round(start, 1)
    return {
        "position": ahead + 1,
        "ahead": ahead,
        "running": running,
        "estimated_start_s": estimate,
        "estimated_start": None if estimate is None else now + timedelta(seconds=estimate),
    }


def places(builtin: bool, per_worker: int) -> int:
    """The places of a worker's ``per_worker`` one episode holds: a built-in's all of them (it computes all
    along), a participant's one (it waits on its policy; robobpp/worker/multiplex.py)."""
    return per_worker if builtin else 1


def start_after(free_in: Sequence[float], pool: int, work: Sequence[tuple[float, int]]) -> float:
    """Seconds until a slot is free for the claim after ``work``: the pool's ``pool`` slots free after
    ``free_in`` (the running episodes' remaining seconds; the other slots are free now); ``work`` is, per
    participant ahead, (episode seconds, episodes), claimed in turn (the fair order gives each a slot in
    turn). Each episode takes the slot that frees first and holds it its time."""
    slots = sorted(free_in) + [0.0] * max(0, pool - len(free_in))
    heapq.heapify(slots)
    turns = itertools.chain.from_iterable(itertools.zip_longest(*(itertools.repeat(t, n) for t, n in work)))
    placed = 0.0
    for t in itertools.islice((t for t in turns if t is not None), SIMULATED):
        heapq.heappush(slots, heapq.heappop(slots) + t)
        placed += t
    return slots[0] + max(0.0, sum(t * n for t, n in work) - placed) / len(slots)


class EpisodeTimes:
    """Expected episode times, read once per estimate in a few statements whatever the number of
    submissions: the running episodes, the recent finished ones' mean per setting, and for ``submissions``
    (and the running episodes' ones) their settings and their own finished episodes' mean."""

    def __init__(self, session: Session, now: datetime, submissions: Collection[int]) -> None:
        self.running = _running_episodes(session, now)
        self.typical = _typical_s(session)
        ids = sorted(set(submissions) | {e.submission_id for e in self.running})
        self.own = _own_s(session, ids)
        self.settings: dict[int, list[str]] = {
            sid: [str(x) for x in settings or []]
            for sid, settings in session.execute(
                select(Submission.id, Submission.settings).where(Submission.id.in_(ids))
            )
        }

    def typical_s(self, settings: Sequence[str]) -> float | None:
        """The recent mean episode time of these settings (their mean), or of any setting."""
        known = [self.typical[s] for s in settings if s in self.typical]
        return statistics.fmean(known) if known else self.typical.get("")

    def of_running(self, episode: Running) -> float | None:
        """A running episode's expected whole time."""
        if (own := self.own.get(episode.submission_id)) is not None:
            return own
        if (paced := episode.paced_s) is not None:
            return paced
        return self.typical_s([episode.setting])

    def remaining(self, episode: Running) -> float | None:
        """A running episode's expected remaining time (0 once it has run past its expected time)."""
        whole = self.of_running(episode)
        return None if whole is None else max(0.0, whole - episode.elapsed_s)

    def of_submission(self, submission_id: int) -> float | None:
        """The expected time of a submission's episodes: its own finished ones', else its running ones' pace,
        else its settings' typical time."""
        if (own := self.own.get(submission_id)) is not None:
            return own
        paced = [t for e in self.running if e.submission_id == submission_id and (t := e.paced_s) is not None]
        if paced:
            return statistics.fmean(paced)
        return self.typical_s(self.settings.get(submission_id, []))


def _own_s(session: Session, ids: Sequence[int]) -> dict[int, float]:
    """Mean time of each submission's newest :data:`OWN_EPISODES` finished episodes (those with any), in one
    statement through the (submission, status) index."""
    if not ids:
        return {}
    ranked = (
        select(
            EpisodeRow.submission_id,
            EpisodeRow.started_at,
            EpisodeRow.finished_at,
            func.row_number()
            .over(partition_by=EpisodeRow.submission_id, order_by=EpisodeRow.id.desc())
            .label("newest"),
        )
        .where(EpisodeRow.submission_id.in_(ids), EpisodeRow.status == "done")
        .subquery()
    )
    spans: defaultdict[int, list[float]] = defaultdict(list)
    for sid, started, finished in session.execute(
        select(ranked.c.submission_id, ranked.c.started_at, ranked.c.finished_at).where(
            ranked.c.newest <= OWN_EPISODES
        )
    ):
        if started is not None and finished is not None:
            spans[sid].append((finished - started).total_seconds())
    return {sid: statistics.fmean(values) for sid, values in spans.items()}


def _running_episodes(session: Session, now: datetime) -> list[Running]:
    """The running episodes (as many as the pool's slots: the claim index finds them)."""
    rows = session.execute(
        select(
            EpisodeRow.submission_id,
            EpisodeRow.setting,
            EpisodeRow.started_at,
            EpisodeRow.step,
            EpisodeRow.boxes_total,
            Submission.policy_url,
        )
        .join(Submission, Submission.id == EpisodeRow.submission_id)
        .where(EpisodeRow.status == "running")
    )
    return [
        Running(
            sid,
            setting,
            max(0.0, (now - started).total_seconds()) if started else 0.0,
            step or 0,
            boxes,
            is_baseline(url),
        )
        for sid, setting, started, step, boxes, url in rows
    ]


def _own_before(session: Session, sub: Submission) -> int:
    """Episodes of ``sub``'s participant that the claim takes before ``sub``'s first
    (:func:`robobpp.db.work.submission_order`)."""
    mine = (is_baseline(sub.policy_url), sub.id)
    before: list[int] = []
    queued = 0
    for sid, url, status, total in session.execute(
        select(Submission.id, Submission.policy_url, Submission.status, Submission.episodes_total).where(
            Submission.participant_id == sub.participant_id,
            Submission.status.in_(ACTIVE_SUBMISSION),
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


def _typical_s(session: Session) -> dict[str, float]:
    """Mean duration of the last finished episodes per setting, and of all of them under ``""``, among the
    newest :data:`RECENT_WINDOW` rows (a primary-key range: the cost is the same with 2.7 M finished episodes
    as with none finished)."""
    newest = session.execute(select(func.max(EpisodeRow.id))).scalar_one()
    if newest is None:
        return {}
    recent = (
        select(EpisodeRow.setting, EpisodeRow.started_at, EpisodeRow.finished_at)
        .where(
            EpisodeRow.id > newest - RECENT_WINDOW,
            EpisodeRow.status == "done",
            EpisodeRow.started_at.is_not(None),
            EpisodeRow.finished_at.is_not(None),
        )
        .order_by(EpisodeRow.id.desc())
        .limit(RECENT_EPISODES)
    )
    spans: defaultdict[str, list[float]] = defaultdict(list)
    # the statement leaves out unset times; the check says so to the type checker
    for setting, s, f in session.execute(recent):
        if s is not None and f is not None:
            spans[setting].append((f - s).total_seconds())
            spans[""].append((f - s).total_seconds())
    return {setting: statistics.fmean(values) for setting, values in spans.items()}


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
    #: Seconds until the last episode ends at that mean on ``workers`` workers of ``per_worker`` places each
    #: (None: nothing measured yet).
    expected_s: float | None
    expected_end: datetime | None


def backlog(
    session: Session, workers: int, now: datetime | None = None, *, per_worker: int = 1
) -> Backlog | None:
    """The unfinished work (``None`` when every submission has finished), and when it should end on
    ``workers`` workers each keeping ``per_worker`` episodes in flight (a built-in's episode takes a whole
    worker, a participant's one place: :func:`places`). Reads the active submissions and their episodes by the
    (submission, status) index, never the backlog row by row: queued submissions count by their
    ``episodes_total``."""
    now = now or utcnow()
    active = session.execute(
        select(Submission.id, Submission.status, Submission.episodes_total, Participant.is_builtin)
        .join(Participant, Participant.id == Submission.participant_id)
        .where(Submission.status.in_(ACTIVE_SUBMISSION))
    ).all()
    if not active:
        return None
    builtin = {sid: bool(is_builtin) for sid, _, _, is_builtin in active}
    queued = [(sid, total) for sid, status, total, _ in active if status == "queued"]
    running_ids = [sid for sid, status, _, _ in active if status == "running"]
    left = sum(total for _, total in queued)
    # the places the work left holds, one episode after another: what the pool's places share
    held = sum(total * places(builtin[sid], per_worker) for sid, total in queued)
    episodes_running = 0
    if running_ids:
        for sid, status, n in session.execute(
            select(EpisodeRow.submission_id, EpisodeRow.status, func.count())
            .where(
                EpisodeRow.submission_id.in_(running_ids),
                EpisodeRow.status.in_(("pending", "waiting", "running")),
            )
            .group_by(EpisodeRow.submission_id, EpisodeRow.status)
        ):
            left += int(n)
            held += int(n) * places(builtin[sid], per_worker)
            if status == "running":
                episodes_running += int(n)
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
    mean_s = _typical_s(session).get("")
    expected = None
    if mean_s is not None:
        expected = round(math.ceil(held / max(1, workers * per_worker)) * mean_s, 1)
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
