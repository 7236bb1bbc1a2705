"""The service's progress in its log: a line per finished submission, and while work waits a line a minute with
the backlog and its expected end (the same figures as the home page's, :func:`robobpp.db.waiting.backlog`).

It runs in the process that started the server (one per deployment, beside the workers); it only reads SQL.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from datetime import datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from robobpp.db.models import Participant, Submission, utcnow
from robobpp.db.waiting import Backlog, backlog
from robobpp.vocabulary import ACTIVE_SUBMISSION, TRACKS
from robobpp.web import SETTING_TITLES

log = logging.getLogger("robobpp.server")

#: Seconds between looks for finished submissions.
POLL_S = 5.0
#: Seconds between backlog lines while work waits.
BACKLOG_LINE_S = 60.0
#: Tracks whose finished submissions are reported (``finished_at`` is indexed with the track).


def duration(seconds: float) -> str:
    """``45 s``, ``12 min``, ``2 h 05 min``: a duration for a person."""
    seconds = max(0.0, seconds)
    if seconds < 90:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60:02d} min"


def clock(when: datetime) -> str:
    """A moment as this machine's local time of day (the log lines' own clock)."""
    return when.astimezone().strftime("%H:%M:%S")


def backlog_line(b: Backlog, workers: int, per_worker: int = 1) -> str:
    """One sentence: what waits, what runs, the baselines' state and when it all should end."""
    done = b.baselines.get("completed", 0) + b.baselines.get("failed", 0)
    total = sum(b.baselines.values())
    text = (
        f"backlog: {b.queued} submission(s) queued, {b.running} running; {b.episodes_left} episode(s) left, "
        f"{b.episodes_running} running"
    )
    if total:
        text += f"; baselines {done} of {total} done"
    if b.expected_s is None or b.expected_end is None:
        return text + "; expected end: after the first episodes finish"
    return (
        f"{text}; expected end {clock(b.expected_end)} (in about {duration(b.expected_s)}: "
        f"{b.mean_episode_s or 0:.1f} s an episode on {workers} worker(s)"
        + (f" of {per_worker} places each)" if per_worker > 1 else ")")
    )


class ProgressLog:
    """A daemon thread that writes the log lines (:meth:`stop` ends it)."""

    def __init__(
        self,
        session: Callable[[], AbstractContextManager[Session]],
        workers: int,
        *,
        per_worker: int = 1,
        poll_s: float = POLL_S,
        every_s: float = BACKLOG_LINE_S,
    ) -> None:
        self._session = session
        self._workers = max(1, workers)
        self._per_worker = max(1, per_worker)
        self._poll_s = poll_s
        self._every_s = every_s
        self._stop = threading.Event()
        self._since = utcnow()
        self._thread = threading.Thread(target=self._run, name="robobpp-progress-log", daemon=True)

    def start(self) -> ProgressLog:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def _run(self) -> None:
        last_line = -float("inf")
        had_work = False
        first = True
        while first or not self._stop.wait(self._poll_s):
            first = False
            try:
                with self._session() as session:
                    finished = list(self._finished(session))
                    b = backlog(session, self._workers, per_worker=self._per_worker)
            except Exception:
                log.debug("progress log: could not read the database", exc_info=True)
                continue
            for line in finished:
                log.info("%s", line)
            if b is None:
                if had_work:
                    log.info("backlog: every submission has finished")
                had_work = False
                continue
            now = time.monotonic()
            if finished or not had_work or now - last_line >= self._every_s:
                log.info("%s", backlog_line(b, self._workers, self._per_worker))
                last_line = now
            had_work = True

    def _finished(self, session: Session) -> Iterator[str]:
        """A line per submission finished since the last look, oldest first."""
        rows = session.execute(
            select(Submission, Participant.name)
            .join(Participant, Participant.id == Submission.participant_id)
            .where(Submission.track.in_(TRACKS), Submission.finished_at > self._since)
            .order_by(Submission.finished_at, Submission.id)
        ).all()
        for sub, owner in rows:
            assert sub.finished_at is not None  # the query's condition
            self._since = max(self._since, sub.finished_at)
            took = duration((sub.finished_at - sub.created_at).total_seconds())
            why = f": {sub.error}" if sub.status == "failed" and sub.error else ""
            yield (
                f"submission #{sub.id} {sub.name} ({owner}, {sub.track} track) {sub.status} "
                f"{took} after it was submitted, {sub.episodes_total} episode(s){why}"
            )


def page_status(session: Session, settings: Any) -> dict[str, Any]:
    """What the home page and the board pages say above their tables: that this is the demo and what it
    plays, the backlog with its expected end, and baselines queued again because their entries no longer fit
    the server's settings (empty when none applies)."""
    from robobpp.server.bootstrap import BUILTIN_PARTICIPANT, stale_reason

    out: dict[str, Any] = {}
    if settings.demo:
        boxes = f", the first {settings.max_boxes} boxes of each" if settings.max_boxes else ""
        out["demo"] = (
            f"{settings.groups} group(s) per dataset{boxes}, "
            f"{', '.join(SETTING_TITLES.get(s, s) for s in settings.enabled_settings)}"
        )
    b = backlog(session, settings.workers, per_worker=settings.episodes_per_worker)
    if b is not None:
        out["backlog"] = b
        out["as_of"] = utcnow()
    again: dict[str, list[str]] = {}
    history: dict[tuple[str, str], list[Submission]] = {}
    for sub in session.execute(
        select(Submission)
        .join(Participant, Participant.id == Submission.participant_id)
        .where(Participant.name == BUILTIN_PARTICIPANT, Submission.policy_url.startswith("builtin:"))
        .order_by(Submission.id)
    ).scalars():
        history.setdefault((sub.policy_url, sub.track), []).append(sub)
    for subs in history.values():
        latest, older = subs[-1], [s for s in subs[:-1] if s.status == "completed"]
        if latest.status in ACTIVE_SUBMISSION and older:
            reason = stale_reason(session, older[-1], settings)
            if reason is not None:
                again.setdefault(reason, []).append(latest.name)
    if again:
        out["requeued"] = again
    return out
