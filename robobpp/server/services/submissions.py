"""Served forms of submissions, built once per state of the submission.

Once a submission is completed, failed or cancelled, its runs, episodes and progress are final (workers
write only under a live lease, and finishing clears them); only a verification verdict may still be
written onto it. So its API body, its episode list and its page's episode table are keyed by
``(id, status, finished_at, verification)`` — read with the submission's own row, which every route loads
anyway to check who may see it — and built once per process.

A submission still queued or running changes only when one of its episodes changes status (its progress,
phase and runs all follow from that), so where a caller has its episode counts by status (a listed page
reads them in one aggregate) its summary is keyed by them: a backlog of queued submissions is built once,
not at every read of every page that lists it. Without the counts it is built on every read.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeVar

from sqlalchemy.orm import Session

from robobpp.db import queries
from robobpp.db.models import Submission

T = TypeVar("T")
FINISHED = ("completed", "failed", "cancelled")


def stamp(sub: Submission | Any, counts: Mapping[str, int] | None = None) -> tuple[Any, ...] | None:
    """What a submission's served forms depend on, or None when that is unknown. ``sub``: a submission, or
    a row with its ``id, status, finished_at, verification``; ``counts``: its episodes by status, for one
    not finished."""
    if sub.status not in FINISHED or sub.finished_at is None:
        return None if counts is None else (sub.id, sub.status, "waiting", tuple(sorted(counts.items())))
    return sub.id, sub.status, sub.finished_at, json.dumps(sub.verification, sort_keys=True, default=str)


class FinishedViews:
    """An LRU of built forms bounded in bytes (``kind`` names the form: API body, episode list, page
    table…); a form that is not bytes or text counts as ``OTHER_BYTES``."""

    OTHER_BYTES = 8192

    def __init__(self, max_bytes: int = 64 * 2**20) -> None:
        self.max_bytes = max_bytes
        self._items: OrderedDict[tuple[Any, ...], tuple[int, Any]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, kind: tuple[Any, ...], sub: Submission | Any, build: Callable[[], T]) -> T:
        """``sub``'s form ``kind``, built now unless kept (a submission not finished is built every time)."""
        return self.get_many(kind, [sub], lambda _missing: [build()])[0]

    def get_many(
        self,
        kind: tuple[Any, ...],
        subs: Sequence[Submission | Any],
        build: Callable[[list[int]], list[T]],
        counts: Mapping[int, Mapping[str, int]] | None = None,
    ) -> list[T]:
        """The forms ``kind`` of several submissions (a listed page), with the lock taken twice in all, not
        twice per submission: with 20 readers, a contended lock handed over 100 times per page cost each
        page a GIL hand-off per acquisition (a list of 50 then took 150 ms instead of 3). ``build`` gets the
        ids of those not kept, in page order, and returns their forms in that order."""
        counts = counts or {}
        keys = {sub.id: stamp(sub, counts.get(sub.id)) for sub in subs}
        found: dict[int, T] = {}
        with self._lock:
            for sub_id, key in keys.items():
                if key is not None and (hit := self._items.get((*kind, *key))) is not None:
                    self._items.move_to_end((*kind, *key))
                    found[sub_id] = hit[1]
        missing = [sub.id for sub in subs if sub.id not in found]
        built = dict(zip(missing, build(missing) if missing else [], strict=True))
        with self._lock:
            for sub_id, value in built.items():
                key = keys[sub_id]
                if key is None or (*kind, *key) in self._items:
                    continue
                cost = len(value) if isinstance(value, bytes | str) else self.OTHER_BYTES
                self._items[(*kind, *key)] = (cost, value)
                self._bytes += cost
            while self._bytes > self.max_bytes and self._items:
                self._bytes -= self._items.popitem(last=False)[1][0]
        return [found[sub.id] if sub.id in found else built[sub.id] for sub in subs]


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
