"""Board composition: the stored runs of a track made into its boards and overall grids.

:class:`BoardEngine` is what the board worker calls: ``update(track)`` brings the track's boards up to date
with the database and returns the ones that changed since its last call. The functions below compute one
board or grid from scratch (``leaderboard``, ``overall_grid``, ``compute_snapshot``): what the engine must
always equal, and what the CLI, the verification route and the tests use directly.

Keys of a track's boards: ``(dataset, setting)`` for the closed loop, ``(dataset, setting, "paper")`` for a
physical setting under the paper protocol, and ``"grid"`` / ``"grid-paper"`` for the overall grids.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from robobpp.db import queries
from robobpp.db.models import Submission
from robobpp.replay import CLOSED, PAPER, PROTOCOLS
from robobpp.scoring.boards import build_board, build_grid
from robobpp.scoring.metrics import PHYSICAL

SessionFactory = Callable[[], AbstractContextManager[Session]]
#: A track's grids, by protocol.
GRID_KEYS = ("grid", "grid-paper")
BoardKey = tuple[str, ...] | str


def leaderboard(
    session: Session, dataset: str, setting: str, *, track: str = "private", protocol: str = CLOSED
) -> dict[str, Any]:
    """One board, computed now: see :func:`robobpp.scoring.boards.build_board`.

    ``protocol="paper"``: a physical setting's paper-protocol runs (the Math actions replayed); a Math Pack
    board is the same under both."""
    protocol = queries.board_protocol(setting, protocol)
    board = build_board(
        queries.board_rows(session, dataset, setting, track, protocol), dataset, setting, track
    )
    board["protocol"] = protocol
    return board


def overall_grid(
    session: Session,
    *,
    datasets: tuple[str, ...] = queries.DATASETS_ORDER,
    settings: tuple[str, ...] = queries.SETTINGS_ORDER,
    track: str = "private",
    protocol: str = CLOSED,
) -> dict[str, Any]:
    """The paper's overall table (see :func:`robobpp.scoring.boards.build_grid`), computed now;
    ``protocol="paper"``: its physical columns under the paper protocol (the Mean then averages those)."""
    boards = {
        f"{s}/{d}": leaderboard(session, d, s, track=track, protocol=protocol)
        for s in settings
        for d in datasets
    }
    grid = build_grid(boards, datasets, settings, track)
    grid["protocol"] = protocol
    return grid


def compute_snapshot(
    session: Session, datasets: tuple[str, ...], settings: tuple[str, ...], track: str
) -> dict[str, Any]:
    """Every board of a track and its overall grids, computed now: ``{"boards": {(dataset, setting): board,
    (dataset, setting, "paper"): board}, "grid": grid, "grid-paper": grid}`` — closed loop, and the physical
    settings under the paper protocol (a Math Pack board is the same under both). The boards lose the resample
    arrays only the grids need (tens of MB at 10,000 entries)."""
    boards: dict[tuple[str, ...], dict[str, Any]] = {
        (d, st): leaderboard(session, d, st, track=track) for st in settings for d in datasets
    }
    for st in settings:
        for d in datasets:
            if st in PHYSICAL:
                boards[(d, st, PAPER)] = leaderboard(session, d, st, track=track, protocol=PAPER)
    grids = {}
    for protocol in PROTOCOLS:
        shown = {
            f"{st}/{d}": boards[(d, st, protocol) if (d, st, protocol) in boards else (d, st)]
            for st in settings
            for d in datasets
        }
        grids[protocol] = build_grid(shown, datasets, settings, track) | {"protocol": protocol}
    for b in boards.values():
        b.pop("_samples", None)
        b.pop("_stable_samples", None)
    return {"boards": boards, "grid": grids[CLOSED], "grid-paper": grids[PAPER]}


def finished_submissions(session: Session, track: str) -> dict[int, tuple[Any, ...]]:
    """What a track's boards are made of, per finished submission: its finish time, status and verification
    (a verdict is written onto a private entry without it finishing again). Any difference between two reads
    is a change of some board."""
    rows = session.execute(
        select(Submission.id, Submission.finished_at, Submission.status, Submission.verification).where(
            Submission.track == track, Submission.status.in_(("completed", "failed"))
        )
    ).all()
    return {
        sid: (finished, status, queries.board_verdict(verification))
        for sid, finished, status, verification in rows
    }


class BoardEngine:
    """Each track's boards and grids, kept between updates.

    ``update(track)`` reads which finished submissions the track has, and when that moved recomputes the
    boards; it returns only the boards and grids that changed since the previous call (everything on the
    first call of a track). One engine per deployment (the board worker); calls are serialised.
    """

    def __init__(
        self,
        session_factory: SessionFactory,
        datasets: tuple[str, ...] = queries.DATASETS_ORDER,
        settings: tuple[str, ...] = queries.SETTINGS_ORDER,
    ) -> None:
        self.session_factory = session_factory
        self.datasets, self.settings = tuple(datasets), tuple(settings)
        self._lock = threading.Lock()
        self._seen: dict[str, dict[int, tuple[Any, ...]]] = {}
        self._boards: dict[str, dict[BoardKey, dict[str, Any]]] = {}

    def keys(self) -> list[BoardKey]:
        """Every board and grid key of a track, in display order."""
        out: list[BoardKey] = [(d, st) for st in self.settings for d in self.datasets]
        out += [(d, st, PAPER) for st in self.settings if st in PHYSICAL for d in self.datasets]
        return [*out, *GRID_KEYS]

    def update(self, track: str) -> dict[BoardKey, dict[str, Any]]:
        """The track's boards and grids that changed since the last call, now current."""
        with self._lock, self.session_factory() as session:
            seen = finished_submissions(session, track)
            if track in self._boards and seen == self._seen.get(track):
                return {}
            snap = compute_snapshot(session, self.datasets, self.settings, track)
        boards: dict[BoardKey, dict[str, Any]] = {
            **snap["boards"],
            "grid": snap["grid"],
            "grid-paper": snap["grid-paper"],
        }
        with self._lock:
            self._seen[track], self._boards[track] = seen, boards
        return dict(boards)

    def current(self, track: str) -> dict[BoardKey, dict[str, Any]]:
        """Every board and grid of the track as of the last :meth:`update` (empty before it)."""
        with self._lock:
            return dict(self._boards.get(track, {}))
