"""Leaderboards with a version-checked cache, so every read is a dictionary lookup and one small SQL query.

A board (scores, bootstrap intervals, rank intervals) is costly to compute — seconds for 10,000 entries —
and changes only when a submission of its track finishes: its runs are shown only then. So each read asks
SQL for the track's *version* (count and latest finish time of finished submissions, one index-only
aggregate) and recomputes only when it moved. The cache is per process and never trusted without that
check, so several API processes stay correct.

When a large board is stale (its last computation took longer than ``sync_limit_s``), readers keep getting
the previous version while one background thread computes the new one: a busy board never makes a reader
wait seconds, and it is current again as soon as that computation ends.

``refresh_s`` (``ROBOBPP_BOARD_REFRESH_S``, 1 s by default) bounds how often a process asks SQL for the
version: a board may then lag a finished submission by that long, and a read costs no query at all.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from contextlib import AbstractContextManager
from datetime import datetime
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from robobpp.db import queries
from robobpp.db.models import Submission
from robobpp.leaderboard import build_grid

log = logging.getLogger("robobpp.server")
SessionFactory = Callable[[], AbstractContextManager[Session]]


def board_version(session: Session, track: str) -> tuple[Any, ...]:
    """Changes whenever a submission of ``track`` (or, for ``private``, a verification) finishes or is
    removed (ix_submissions_track_finished).

    Read once per session (one request): a page showing several boards checks the version once.
    """
    known: dict[str, tuple[Any, ...]] = session.info.setdefault("board_versions", {})
    if track not in known:
        known[track] = tuple(
            session.execute(
                select(func.count(), func.max(Submission.finished_at)).where(
                    # a verification finishing writes its verdict onto a private entry (db/verification.py)
                    Submission.track.in_((track, "verify") if track == "private" else (track,)),
                    Submission.finished_at.is_not(None),
                )
            ).one()
        )
    return known[track]


def _default(value: object) -> str:
    if isinstance(value, datetime):
        return value.isoformat().replace("+00:00", "Z")
    raise TypeError(f"cannot serialise {type(value).__name__}")


def to_json(data: Any) -> bytes:
    return json.dumps(data, default=_default, allow_nan=False, separators=(",", ":")).encode()


class _Slot:
    __slots__ = ("version", "value", "seconds", "refreshing")

    def __init__(self, version: tuple[Any, ...], value: Any, seconds: float) -> None:
        self.version, self.value, self.seconds, self.refreshing = version, value, seconds, False


class BoardCache:
    """Boards and grids per (track, …), each stored with the track version it was computed at."""

    def __init__(self, session_factory: SessionFactory | None = None, *, size: int = 64,
                 sync_limit_s: float = 0.25, refresh_s: float = 0.0) -> None:  # fmt: skip
        self._slots: dict[tuple[Any, ...], _Slot] = {}
        self._lock = threading.Lock()
        self._computing: dict[tuple[Any, ...], threading.Lock] = {}
        self.session_factory = session_factory
        self.size = size
        self.sync_limit_s = sync_limit_s
        self.refresh_s = refresh_s
        self._versions: dict[str, tuple[float, tuple[Any, ...]]] = {}
        self._responses: OrderedDict[tuple[Any, ...], tuple[tuple[Any, ...], bytes]] = OrderedDict()
        self.responses_size = 512

    def version(self, session: Session, track: str) -> tuple[Any, ...]:
        """The track's version, read from SQL at most every ``refresh_s`` seconds per process: within that
        window a request touches no database at all (SQLite serialises every transaction)."""
        now = time.monotonic()
        with self._lock:
            known = self._versions.get(track)
        if known is not None and now - known[0] < self.refresh_s:
            return known[1]
        version = board_version(session, track)
        with self._lock:
            self._versions[track] = (now, version)
        return version

    def response(
        self, session: Session, track: str, key: tuple[Any, ...], build: Callable[[], bytes]
    ) -> bytes:
        """A served body (a page of a board as JSON, a rendered page) built once per board version: readers
        of the same page share it instead of each serialising or rendering it."""
        version = self.version(session, track)
        with self._lock:
            hit = self._responses.get(key)
            if hit is not None and hit[0] == version:
                self._responses.move_to_end(key)
                return hit[1]
        body = build()
        with self._lock:
            self._responses[key] = (version, body)
            while len(self._responses) > self.responses_size:
                self._responses.popitem(last=False)
        return body

    def board(self, session: Session, dataset: str, setting: str, track: str = "private") -> dict[str, Any]:
        """The full board (``robobpp.leaderboard.build_board``); page it with ``board_view``."""
        version = self.version(session, track)
        return self._get(("board", dataset, setting, track), version, session,
                         lambda s: queries.leaderboard(s, dataset, setting, track=track))  # fmt: skip

    def grid(self, session: Session, datasets: tuple[str, ...], settings: tuple[str, ...],
             track: str = "private") -> dict[str, Any]:  # fmt: skip
        """The overall grid from the (cached) boards; page it with ``grid_view``."""
        version = self.version(session, track)

        def compute(s: Session) -> dict[str, Any]:
            boards = {f"{st}/{d}": self._get(("board", d, st, track), version, s,
                                             lambda s2, d=d, st=st: queries.leaderboard(s2, d, st, track=track),
                                             background=False)  # fmt: skip
                      for st in settings for d in datasets}  # fmt: skip
            return build_grid(boards, datasets, settings, track)

        return self._get(("grid", datasets, settings, track), version, session, compute)

    def _get(self, key: tuple[Any, ...], version: tuple[Any, ...], session: Session,
             compute: Callable[[Session], Any], background: bool = True) -> Any:  # fmt: skip
        with self._lock:
            slot = self._slots.get(key)
            if slot is not None and slot.version == version:
                return slot.value
            if (background and slot is not None and self.session_factory is not None
                    and slot.seconds > self.sync_limit_s):  # fmt: skip
                if not slot.refreshing:
                    slot.refreshing = True
                    threading.Thread(target=self._refresh, args=(key, compute), daemon=True,
                                     name="board-refresh").start()  # fmt: skip
                return slot.value
        return self._store(key, version, compute, session)

    def _store(self, key: tuple[Any, ...], version: tuple[Any, ...], compute: Callable[[Session], Any],
               session: Session) -> Any:  # fmt: skip
        with self._lock:
            key_lock = self._computing.setdefault(key, threading.Lock())
        with key_lock:  # readers arriving together wait for one computation instead of each doing it
            with self._lock:
                slot = self._slots.get(key)
                if slot is not None and slot.version == version:
                    return slot.value
            started = time.perf_counter()
            value = compute(session)
            with self._lock:
                self._slots[key] = _Slot(version, value, time.perf_counter() - started)
                while len(self._slots) > self.size:
                    self._slots.pop(next(iter(self._slots)))
            return value

    def _refresh(self, key: tuple[Any, ...], compute: Callable[[Session], Any]) -> None:
        assert self.session_factory is not None
        try:
            with self.session_factory() as session:
                # the version read first: a submission finishing meanwhile makes the next read refresh again
                session.info.pop("board_versions", None)
                self._store(key, board_version(session, key[-1]), compute, session)
        except Exception:  # noqa: BLE001 - readers keep the previous board; the next stale read retries
            log.exception("board refresh failed for %s", key)
            with self._lock:
                slot = self._slots.get(key)
                if slot is not None:
                    slot.refreshing = False
