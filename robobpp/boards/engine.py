"""Board composition: the stored runs of a track made into its boards and overall grids.

:class:`BoardEngine` is what the board worker calls: ``update(track)`` brings the track's boards up to date
with the database and returns the ones that changed since its last call. The functions below compute one
board or grid from scratch (``leaderboard``, ``overall_grid``, ``compute_snapshot``): what the engine must
always equal, and what the CLI, the verification route and the tests use directly.

Keys of a track's boards (:func:`board_id`, :func:`grid_id`): ``(dataset, setting)`` for the closed loop,
``(dataset, setting, "paper")`` for a physical setting under the paper protocol, and ``"grid"`` /
``"grid-paper"`` for the overall grids — the leaderboard, lookahead 0. Submissions that saw K > 0 next boxes
rank on boards of their own, closed loop only (the paper protocol is there to compare with the paper's tables,
made without lookahead): ``(dataset, setting, "closed", "K")`` and ``"grid-lookahead-K"``, only for the
lookaheads that have entries. Every board and grid carries its ``lookahead`` and the track's ``lookaheads``.
"""

from __future__ import annotations

import ctypes
import dataclasses
import gc
import logging
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from robobpp.boards.grid import GridMatrix, GridSums
from robobpp.boards.matrix import BoardMatrix, PartLoader, SharedFields, Workspace
from robobpp.boards.ranking import build_board, build_grid
from robobpp.boards.records import Board, Grid, Published, as_board, with_lookaheads
from robobpp.db import queries
from robobpp.db.models import Submission
from robobpp.scoring.entries import StoredParts, entry_part
from robobpp.scoring.metrics import PHYSICAL
from robobpp.vocabulary import CLOSED, DATASETS, LOOPS, PAPER, SETTINGS, board_loop

log = logging.getLogger("robobpp.server")
SessionFactory = Callable[[], AbstractContextManager[Session]]
#: A full computation that has run this long says how far it is after each board (at 100,000 submissions one
#: takes 18 minutes, during which the worker was silent).
PROGRESS_AFTER_S = 30.0
BoardKey = tuple[str, ...] | str
_LOOKAHEAD_GRID = "grid-lookahead-"


def board_id(dataset: str, setting: str, loop: str = CLOSED, lookahead: int = 0) -> tuple[str, ...]:
    """A board's key in the engine (module docstring): the one place it is built. A Math Pack board is one
    board under both protocols; a lookahead K > 0 has closed-loop boards only."""
    loop = board_loop(setting, loop)
    if lookahead:
        if loop != CLOSED:
            raise ValueError("a lookahead K > 0 has closed-loop boards only")
        return (dataset, setting, CLOSED, str(lookahead))
    return (dataset, setting) if loop == CLOSED else (dataset, setting, loop)


def grid_id(loop: str = CLOSED, lookahead: int = 0) -> str:
    """A grid's key in the engine: ``grid``, ``grid-paper``, ``grid-lookahead-K``."""
    if lookahead:
        return f"{_LOOKAHEAD_GRID}{lookahead}"
    return "grid" if loop == CLOSED else f"grid-{loop}"


def board_of(key: tuple[str, ...]) -> tuple[str, str, str, int]:
    """What a board key names: (dataset, setting, loop, lookahead)."""
    loop = key[2] if len(key) > 2 else CLOSED
    return key[0], key[1], loop, int(key[3]) if len(key) > 3 else 0


def grid_of(key: str) -> tuple[str, int]:
    """What a grid key names: (loop, lookahead)."""
    if key.startswith(_LOOKAHEAD_GRID):
        return CLOSED, int(key.removeprefix(_LOOKAHEAD_GRID))
    return (PAPER if key.endswith(PAPER) else CLOSED), 0


def lookahead_of(key: BoardKey) -> int:
    return grid_of(key)[1] if isinstance(key, str) else board_of(key)[3]


def lookahead_loops(lookahead: int) -> tuple[str, ...]:
    """The protocols a lookahead has boards under: both for 0, the closed loop only for K > 0."""
    return LOOPS if lookahead == 0 else (CLOSED,)


def leaderboard(
    session: Session,
    dataset: str,
    setting: str,
    *,
    track: str = "private",
    loop: str = CLOSED,
    lookahead: int = 0,
) -> Board:
    """One board, computed now: see :func:`robobpp.boards.ranking.build_board`.

    ``loop="paper"``: a physical setting's paper-protocol runs (the Math actions replayed); a Math Pack
    board is the same under both. ``lookahead``: the board of the submissions that saw that many next boxes
    (0: the leaderboard's)."""
    loop = board_loop(setting, loop)
    if lookahead and loop != CLOSED:
        raise ValueError("a lookahead K > 0 has closed-loop boards only")
    board = build_board(
        queries.board_rows(session, dataset, setting, track, loop, lookahead), dataset, setting, track
    )
    return dataclasses.replace(board, loop=loop, lookahead=lookahead)


def overall_grid(
    session: Session,
    *,
    datasets: tuple[str, ...] = DATASETS,
    settings: tuple[str, ...] = SETTINGS,
    track: str = "private",
    loop: str = CLOSED,
    lookahead: int = 0,
) -> Grid:
    """The paper's overall table (see :func:`robobpp.boards.ranking.build_grid`), computed now;
    ``loop="paper"``: its physical columns under the paper protocol (the Mean then averages those);
    ``lookahead``: of the submissions that saw that many next boxes."""
    boards = {
        f"{s}/{d}": leaderboard(session, d, s, track=track, loop=loop, lookahead=lookahead)
        for s in settings
        for d in datasets
    }
    grid = build_grid(boards, datasets, settings, track)
    return dataclasses.replace(grid, loop=loop, lookahead=lookahead)


def board_triples(datasets: Sequence[str], settings: Sequence[str]) -> list[tuple[str, str, str]]:
    """The (dataset, setting, loop) of a track's lookahead-0 boards: every run any board shows is on one."""
    return [(d, st, CLOSED) for st in settings for d in datasets] + [
        (d, st, PAPER) for st in settings if st in PHYSICAL for d in datasets
    ]


def track_lookaheads(
    session: Session, track: str, datasets: Sequence[str], settings: Sequence[str]
) -> list[int]:
    """The lookaheads with boards on ``track``: 0 (the leaderboard) and each K > 0 some closed-loop run saw."""
    closed = [t for t in board_triples(datasets, settings) if t[2] == CLOSED]
    return [0, *queries.board_lookaheads(session, track, closed)]


def compute_snapshot(
    session: Session, datasets: tuple[str, ...], settings: tuple[str, ...], track: str
) -> dict[BoardKey, Published]:
    """Every board of a track and its overall grids, computed now, by key as the engine hands them out:
    ``(dataset, setting)``, ``(dataset, setting, "paper")``, ``(dataset, setting, "closed", "K")``, ``"grid"``,
    ``"grid-paper"``, ``"grid-lookahead-K"`` — closed loop, the physical settings under the paper protocol (a
    Math Pack board is the same under both), and the closed loop of each lookahead K > 0 with entries (keys:
    :func:`board_id`, :func:`grid_id`). The boards lose the resample arrays only the grids need (tens of MB at
    10,000 entries)."""
    lookaheads = track_lookaheads(session, track, datasets, settings)
    boards: dict[tuple[str, ...], Board] = {}
    grids: dict[str, Grid] = {}
    for lookahead in lookaheads:
        for loop in lookahead_loops(lookahead):
            for st in settings:
                for d in datasets:
                    key = board_id(d, st, loop, lookahead)
                    if key not in boards:
                        boards[key] = leaderboard(session, d, st, track=track, loop=loop, lookahead=lookahead)
            shown = {
                f"{st}/{d}": boards[board_id(d, st, loop, lookahead)] for st in settings for d in datasets
            }
            grid = build_grid(shown, datasets, settings, track)
            grids[grid_id(loop, lookahead)] = dataclasses.replace(grid, loop=loop, lookahead=lookahead)
    out: dict[BoardKey, Published] = {key: board.served() for key, board in boards.items()}
    out.update(grids)
    with_lookaheads(out, list(out), lookaheads)
    return out


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


@dataclass
class _Track:
    """What the engine keeps of one track between updates."""

    seen: dict[int, tuple[Any, ...]]
    boards: dict[tuple[str, ...], BoardMatrix]
    out: dict[BoardKey, Published] = field(default_factory=dict)
    #: The grids kept between updates, by grid key.
    grids: dict[str, GridMatrix] = field(default_factory=dict)
    #: The lookaheads with boards (0 always), as every board and grid handed out says.
    lookaheads: list[int] = field(default_factory=lambda: [0])
    #: Each submission's fields every board shows alike, kept once for the track's boards.
    shared: SharedFields = field(default_factory=SharedFields)


@dataclass(frozen=True, slots=True)
class _Gathering:
    """A full computation's grid sums (:class:`~robobpp.boards.grid.GridSums`): by grid key, and by board key
    the sums that board is added to, with its cell's key in the grid."""

    by_grid: dict[str, GridSums]
    by_board: dict[tuple[str, ...], list[tuple[GridSums, str]]]


class BoardEngine:
    """Each track's boards and grids, kept between updates (:class:`robobpp.boards.matrix.BoardMatrix`).

    ``update(track)`` reads which finished submissions the track has; the boards of those that arrived,
    changed or left are updated — only the global part of the scoring: each run's own part was stored when
    it finished — and returned with the grids of their lookahead, if any moved; nothing else is touched. The
    boards of a lookahead K > 0 come with its first entry and go with its last (when the set of lookaheads
    changes, every board and grid says so: all are returned). The all-entries rank intervals (boards and
    grids) are computed by ``refresh(track)``, the full computation the board worker runs on a timer; the
    first ``update`` of a track is one. One engine per deployment; calls are serialised.
    """

    def __init__(
        self,
        session_factory: SessionFactory,
        datasets: tuple[str, ...] = DATASETS,
        settings: tuple[str, ...] = SETTINGS,
    ) -> None:
        self.session_factory = session_factory
        self.datasets, self.settings = tuple(datasets), tuple(settings)
        self._lock = threading.Lock()
        self._tracks: dict[str, _Track] = {}

    def _large(self) -> bool:
        """Whether the boards hold enough entries to freeze them (:data:`FREEZE_ENTRIES`)."""
        entries = sum(len(m) for state in self._tracks.values() for m in state.boards.values())
        return entries >= FREEZE_ENTRIES

    def keys(self, track: str | None = None) -> list[BoardKey]:
        """Every board and grid key of a track (None: of lookahead 0, which every track has), in display
        order."""
        state = self._tracks.get(track) if track is not None else None
        out: list[BoardKey] = []
        for lookahead in state.lookaheads if state is not None else [0]:
            out += self._board_keys(lookahead)
            out += [grid_id(p, lookahead) for p in lookahead_loops(lookahead)]
        return out

    def _board_keys(self, lookahead: int = 0) -> list[tuple[str, ...]]:
        return [
            board_id(d, st, loop, lookahead)
            for loop in lookahead_loops(lookahead)
            for st in self.settings
            if loop == CLOSED or st in PHYSICAL
            for d in self.datasets
        ]

    def update(self, track: str) -> dict[BoardKey, Published]:
        """The track's boards and grids that changed since the last call, now current."""
        with self._lock:
            if track not in self._tracks:
                with _collector_paused(full=True, large=self._large):
                    return self._full(track)
            with _collector_paused(full=False, large=self._large):
                return self._update(track)

    def _update(self, track: str) -> dict[BoardKey, Published]:
        state = self._tracks[track]
        with self.session_factory() as session:
            seen = finished_submissions(session, track)
            added = [s for s in seen if s not in state.seen]
            changed = [s for s in seen if s in state.seen and seen[s] != state.seen[s]]
            removed = [s for s in state.seen if s not in seen]
            if not (added or changed or removed):
                return {}
            runs, parts = self._runs(session, track, added + changed) if added or changed else ([], {})
        touched: set[tuple[str, ...]] = set()
        by_board: dict[tuple[str, ...], list[dict[str, Any]]] = {}
        for run in runs:
            by_board.setdefault(self._key_of(run), []).append(run)
        before = state.lookaheads
        # a lookahead's first entry brings its boards (all of them computed now: its grid needs them)
        self._add_lookaheads(track, state, {board_of(key)[3] for key in by_board})
        touched.update(key for key in state.boards if key not in state.out)
        for key, matrix in state.boards.items():
            upsert = by_board.get(key, [])
            present = {int(r["submission_id"]) for r in upsert}
            gone = [s for s in (*removed, *changed) if s in matrix and s not in present]
            if upsert or gone:
                matrix.apply(upsert, gone, parts=parts.get(key))
                touched.add(key)
        state.seen = seen
        state.shared.keep_only(seen)
        self._drop_empty(state)  # and its last takes them away
        touched &= state.boards.keys()
        out: list[BoardKey] = []
        for key in touched:
            state.out[key] = state.boards[key].board()
            out.append(key)
        if touched:
            out += self._grids(track, state, {board_of(k)[3] for k in touched}, full=False)
        if state.lookaheads != before:  # every board and grid names the lookaheads: all handed out again
            out = list(state.out)
        with_lookaheads(state.out, out, state.lookaheads)
        return {k: state.out[k].served() for k in out}

    def refresh(self, track: str) -> dict[BoardKey, Published]:
        """Every board and grid of the track computed in full (rank intervals of every entry included)."""
        with self._lock, _collector_paused(full=True, large=self._large):
            return self._full(track)

    def current(self, track: str) -> dict[BoardKey, Published]:
        """Every board and grid of the track as of the last update (empty before the first)."""
        with self._lock:
            state = self._tracks.get(track)
            return {} if state is None else {k: v.served() for k, v in state.out.items()}

    def _add_lookaheads(self, track: str, state: _Track, lookaheads: set[int]) -> None:
        """Empty boards for the lookaheads that have none yet."""
        for lookahead in sorted(lookaheads - set(state.lookaheads)):
            for key in self._board_keys(lookahead):
                state.boards[key] = self._matrix(track, key, state.shared)
            # a new list (never changed in place): the boards handed out hold the one they were given
            state.lookaheads = sorted({*state.lookaheads, lookahead})

    def _matrix(self, track: str, key: tuple[str, ...], shared: SharedFields) -> BoardMatrix:
        dataset, setting, loop, lookahead = board_of(key)
        return BoardMatrix(dataset, setting, track, loop, self._loader(track, key), lookahead, shared)

    def _drop_empty(self, state: _Track) -> None:
        """Forget the boards and grids of each lookahead K > 0 no entry is on any longer."""
        for lookahead in state.lookaheads[1:]:
            keys = self._board_keys(lookahead)
            if any(len(state.boards[k]) for k in keys):
                continue
            for key in keys:
                del state.boards[key]
                state.out.pop(key, None)
            for loop in lookahead_loops(lookahead):
                state.grids.pop(grid_id(loop, lookahead), None)
                state.out.pop(grid_id(loop, lookahead), None)
            state.lookaheads = [k for k in state.lookaheads if k != lookahead]

    def _full(self, track: str) -> dict[BoardKey, Published]:
        with self.session_factory() as session:
            seen = finished_submissions(session, track)
            lookaheads = track_lookaheads(session, track, self.datasets, self.settings)
        state = self._tracks.get(track)
        if state is None:
            shared = SharedFields()
            boards = {key: self._matrix(track, key, shared) for key in self._board_keys()}
            state = _Track(seen, boards, shared=shared)
        self._add_lookaheads(track, state, set(lookaheads))
        gathering = self._gathering(state)
        workspace = Workspace()  # the large arrays, reused board after board; dropped with this call
        started = time.monotonic()
        for done, (key, matrix) in enumerate(state.boards.items(), start=1):
            # One board's runs at a time, read after ``seen`` (so never older than it), computed and dropped
            # before the next board's are read: every run of the track decoded at once (its row and stored
            # part, ≈ 6 kB a run) made the start-up peak far above what the boards keep (100,000
            # submissions: past 21 GB). Its parts pass to the board, read once.
            with self.session_factory() as session:
                rows, parts = self._runs(session, track, None, keys=[key])
            present = {int(r["submission_id"]) for r in rows}
            matrix.apply(rows, [s for s in matrix.submission_ids() if s not in present], parts=parts.get(key))
            del rows, parts
            state.out[key] = matrix.board(
                rank_intervals=True, for_grid=key in gathering.by_board, workspace=workspace
            )
            if key in gathering.by_board:
                ids, rel, stable = matrix.take_grid_samples()
                for sums, cell in gathering.by_board[key]:
                    sums.add(cell, ids, rel, stable)
                del rel, stable
            if (elapsed := time.monotonic() - started) >= PROGRESS_AFTER_S:
                log.info(
                    "computing the %s boards in full: %d of %d done (%s, %d entries) after %.0f s",
                    track,
                    done,
                    len(state.boards),
                    "/".join(key),
                    len(matrix),
                    elapsed,
                )
        del workspace  # before the grids are computed: their arrays are not the boards'
        state.seen = seen
        state.shared.keep_only(seen)
        self._drop_empty(state)
        self._grids(track, state, set(state.lookaheads), full=True, gathered=gathering.by_grid)
        self._tracks[track] = state
        with_lookaheads(state.out, list(state.out), state.lookaheads)
        return {k: v.served() for k, v in state.out.items()}

    def _gathering(self, state: _Track) -> _Gathering:
        """A full computation's sums for each grid of the track, by grid and by the boards each one reads."""
        out = _Gathering({}, {})
        for lookahead in state.lookaheads:
            for loop in lookahead_loops(lookahead):
                cells = self._grid_cells(loop, lookahead)
                sums = out.by_grid[grid_id(loop, lookahead)] = GridSums(list(cells))
                for cell, key in cells.items():
                    out.by_board.setdefault(key, []).append((sums, cell))
        return out

    def _grid_cells(self, loop: str, lookahead: int) -> dict[str, tuple[str, ...]]:
        """A grid's cells (``setting/dataset``, in the grid's order) -> the key of the board each one shows."""
        return {f"{st}/{d}": board_id(d, st, loop, lookahead) for st in self.settings for d in self.datasets}

    def _grids(
        self,
        track: str,
        state: _Track,
        lookaheads: set[int],
        *,
        full: bool,
        gathered: Mapping[str, GridSums] | None = None,
    ) -> list[BoardKey]:
        """The grids of ``lookaheads`` from their boards (those of other lookaheads cannot have moved): kept in
        ``state.out``; their keys. ``gathered``: each grid's sums as a full computation gathered them."""
        out: list[BoardKey] = []
        for lookahead in sorted(lookaheads):
            for loop in lookahead_loops(lookahead):
                cells = self._grid_cells(loop, lookahead)
                shown = {cell: as_board(state.out[key]) for cell, key in cells.items()}
                grid_key = grid_id(loop, lookahead)
                matrix = state.grids.get(grid_key)
                if matrix is None:
                    matrix = state.grids[grid_key] = GridMatrix(self.datasets, self.settings, track)
                matrices = {cell: state.boards[key] for cell, key in cells.items()}
                grid = matrix.grid(
                    shown,
                    matrices,
                    rank_intervals=full,
                    loop=loop,
                    lookahead=lookahead,
                    gathered=(gathered or {}).get(grid_key),
                )
                state.out[grid_key] = grid
                out.append(grid_key)
        return out

    def _key_of(self, run: Mapping[str, Any]) -> tuple[str, ...]:
        loop = PAPER if run["setting"] in PHYSICAL and run["protocol"] == PAPER else CLOSED
        return board_id(run["dataset"], run["setting"], loop, int(run.get("lookahead") or 0))

    def _runs(
        self,
        session: Session,
        track: str,
        submission_ids: list[int] | None,
        keys: Sequence[tuple[str, ...]] | None = None,
    ) -> tuple[list[dict[str, Any]], dict[tuple[str, ...], StoredParts]]:
        """The track's runs on this engine's boards (``keys``: on those; else of every lookahead), each with
        its group ``ids`` (None: no figures); and by board, its runs' parts (decoded at once)."""
        if keys is None:
            # the boards' (dataset, setting, loop) of every lookahead; a lookahead K > 0 has no
            # paper-protocol boards: its replays are shown on none
            runs = queries.board_runs(
                session,
                track,
                boards=board_triples(self.datasets, self.settings),
                submission_ids=submission_ids,
            )
            runs = [r for r in runs if not (r["lookahead"] and r["protocol"] != CLOSED)]
        else:
            runs = []
            for key in keys:
                d, st, loop, lookahead = board_of(key)
                runs += queries.board_runs(
                    session,
                    track,
                    boards=[(d, st, loop)],
                    submission_ids=submission_ids,
                    lookahead=lookahead,
                )
        by_board: dict[tuple[str, ...], list[dict[str, Any]]] = {}
        for run in runs:
            by_board.setdefault(self._key_of(run), []).append(run)
        parts: dict[tuple[str, ...], StoredParts] = {}
        for key, on_board in by_board.items():
            d, st, loop, _ = board_of(key)
            sids = [int(run["submission_id"]) for run in on_board]
            found, undecoded = StoredParts.decode(st, sids, [run.pop("entry") for run in on_board])
            if undecoded:  # stored before 0010 or by an older version: computed here
                lacking = [sids[k] for k in undecoded]
                _computed(found, lacking, queries.run_figures_of(session, track, d, st, loop, lacking))
            for run in on_board:
                ids = found.ids_of(run["submission_id"])
                run["ids"] = None if ids is None else _interned(ids)
            parts[key] = found
        return runs, parts

    def _loader(self, track: str, key: tuple[str, ...]) -> PartLoader:
        dataset, setting, loop, _ = board_of(key)

        def load(submission_ids: Sequence[int]) -> StoredParts:
            sids = [int(s) for s in submission_ids]
            with self.session_factory() as session:
                stored = queries.run_entries_of(session, track, dataset, setting, loop, sids)
                parts, undecoded = StoredParts.decode(setting, sids, [stored.get(s) for s in sids])
                if undecoded:
                    lacking = [sids[k] for k in undecoded]
                    figures = queries.run_figures_of(session, track, dataset, setting, loop, lacking)
                    _computed(parts, lacking, figures)
            return parts

        return load


#: Past this many entries on a deployment's boards (about 1,000 submissions) the engine freezes what it keeps
#: after each computation (``_collector_paused``). Below it a full collection is cheap, and the collector
#: runs as usual; a small deployment's full computations stay a fraction of a second.
FREEZE_ENTRIES = 15_000


@contextmanager
def _collector_paused(*, full: bool, large: Callable[[], bool]) -> Iterator[None]:
    """Run a board computation without Python's cyclic garbage collector; a ``large`` engine then freezes
    what is alive.

    The engine keeps millions of small objects between updates (≈ 3 million at 10,000 submissions: every
    entry's row, figures and served row). An update allocates enough to trigger the collector's full passes,
    and each walks all of them: 1.5–2.5 s of the ≈ 7 s a middling update took at 10,000 submissions
    (BENCHMARKS.md, "Board updates"). So the collector waits while the engine computes, and afterwards what
    is alive is frozen (``gc.freeze``): later passes skip it. A frozen object is still freed when its last
    reference goes; only a cycle among frozen objects waits — for the next full computation (``full``: the
    start, and the worker's timer), which unfreezes and collects everything before it freezes again (some of
    the objects it replaced are in cycles: 500 MB at 10,000 submissions), and hands the freed heap back to
    the system."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
        freeze = large()
        if full:
            gc.unfreeze()
            if freeze:
                gc.collect()
        if freeze:
            gc.freeze()
        if full:
            trim_heap()


def trim_heap() -> None:
    """Hand the C heap's free pages back to the system after a full computation, or a publication: a full
    computation replaces every entry's objects and glibc keeps what the old ones freed (0.4 GB after the
    start, 1.2 GB after a refresh at 10,000 submissions), a publication what its rows' bodies took (150 MB
    after a first publication at 10,000: BENCHMARKS.md, "The board engine"). Nothing elsewhere than glibc."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return
    trim(0)


_IDS: dict[bytes, bytes] = {}


def _interned(ids: bytes) -> bytes:
    """One object per distinct group-id list (every entry of a board has the same)."""
    return _IDS.setdefault(ids, ids)


def _computed(parts: StoredParts, lacking: Sequence[int], figures: Mapping[int, Any]) -> None:
    """The parts of runs ``lacking`` a stored one (or one of another format), from their ``figures`` (None:
    no figures)."""
    for sid in lacking:
        f = figures.get(sid)
        parts.set(sid, entry_part(f, parts.setting) if f and f.get("ids") else None)
