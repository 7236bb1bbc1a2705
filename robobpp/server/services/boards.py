"""Leaderboards with a version-checked cache.

Scores are computed on read (they are relative), but a board only changes when a run on it completes or a
submission on it finishes; so each read first asks SQL for the board's *version* (count and latest
timestamps, two indexed aggregates) and recomputes only when it moved. The cache is per process and never
trusted without that check, so several API processes stay correct.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from datetime import datetime
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from robobpp.db import queries
from robobpp.db.models import RunRow, Submission
from robobpp.scoring import WEIGHTS


def board_version(session: Session, dataset: str, setting: str, track: str) -> tuple[Any, ...]:
    runs = session.execute(
        select(func.count(), func.max(RunRow.completed_at), func.max(RunRow.id)).where(
            RunRow.dataset == dataset, RunRow.setting == setting, RunRow.status == "completed")
    ).one()  # fmt: skip
    subs = session.execute(
        select(func.count(), func.max(Submission.finished_at)).where(Submission.track == track,
                                                                      Submission.finished_at.is_not(None))
    ).one()  # fmt: skip
    return (*runs, *subs)


def _default(value: object) -> str:
    if isinstance(value, datetime):
        return value.isoformat().replace("+00:00", "Z")
    raise TypeError(f"cannot serialise {type(value).__name__}")


def to_json(data: Any) -> bytes:
    return json.dumps(data, default=_default, allow_nan=False, separators=(",", ":")).encode()


class BoardCache:
    def __init__(self, size: int = 64) -> None:
        self._data: OrderedDict[tuple[str, str, str], tuple[tuple[Any, ...], dict[str, Any], bytes]] = (
            OrderedDict()
        )
        self._lock = threading.Lock()
        self.size = size

    def get(
        self, session: Session, dataset: str, setting: str, track: str = "private"
    ) -> tuple[dict[str, Any], bytes]:
        """The board (dict, as :func:`robobpp.db.queries.leaderboard` plus ``weights``) and its JSON."""
        key = (dataset, setting, track)
        version = board_version(session, dataset, setting, track)
        with self._lock:
            hit = self._data.get(key)
            if hit is not None and hit[0] == version:
                self._data.move_to_end(key)
                return hit[1], hit[2]
        data = {**queries.leaderboard(session, dataset, setting, track=track), "weights": WEIGHTS[setting]}
        body = to_json(data)
        with self._lock:
            self._data[key] = (version, data, body)
            while len(self._data) > self.size:
                self._data.popitem(last=False)
        return data, body


def overall_grid(cache: BoardCache, session: Session, datasets: tuple[str, ...], settings: tuple[str, ...],
                 track: str = "private") -> dict[str, Any]:  # fmt: skip
    """The 3 × 3 grid from (cached) boards: one row per submission, a (score, rank) cell per board."""
    return queries.overall_grid(session, datasets=datasets, settings=settings, track=track,
                                board=lambda dataset, setting: cache.get(session, dataset, setting, track)[0])  # fmt: skip
