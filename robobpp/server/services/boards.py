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

The board process also stores each snapshot it computes in the state directory (``boards-<track>.pickle``,
written whole then renamed). A restarted server loads it before it answers anyone, serves it at once and
recomputes in the background, always (the code or the data may have changed while it was down): a restart
at 10,000 submissions no longer leaves readers waiting the minute a snapshot takes. The file is the
server's own, as trusted as the SQLite database beside it; one that does not load, or was written by
another version, database or board set, is ignored.
"""

from __future__ import annotations

import gc
import hashlib
import json
import logging
import math
import multiprocessing
import os
import pickle
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import AbstractContextManager, contextmanager
from datetime import datetime
from pathlib import Path
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from robobpp import __version__
from robobpp.datasets.sampling import SAMPLER_VERSION
from robobpp.db import queries
from robobpp.db.models import Submission
from robobpp.replay import CLOSED
from robobpp.server.services.board_engine import GRID_KEYS, compute_snapshot, leaderboard
from robobpp.sim.math_pack import MATH_RULES_VERSION
from robobpp.sim.physics.config import PHYSICS_VERSION

try:  # POSIX: the API processes of one host compute each snapshot once (BoardCache._host_lock)
    import fcntl
except ImportError:  # pragma: no cover - Windows: each process computes its own
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger("robobpp.server")
SessionFactory = Callable[[], AbstractContextManager[Session]]


def board_version(session: Session, track: str) -> tuple[Any, ...]:
    """Changes whenever a submission of ``track`` (or, for ``private``, a verification) finishes or is
    removed (ix_submissions_track_finished), and for ``private`` when a verification starts.

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
        if track == "private":  # a verification starting shows "pending" on its entry at once
            known[track] += (
                session.execute(select(func.count()).where(Submission.track == "verify")).scalar_one(),
            )
    return known[track]


def _default(value: object) -> str:
    if isinstance(value, datetime):
        return value.isoformat().replace("+00:00", "Z")
    raise TypeError(f"cannot serialise {type(value).__name__}")


def to_json(data: Any) -> bytes:
    return json.dumps(data, default=_default, allow_nan=False, separators=(",", ":")).encode()


_CHILD_FACTORIES: dict[str, Any] = {}
#: Bumped when a stored snapshot's layout changes (``_stored_key``). 2: paper-protocol boards and grid.
STORE_FORMAT = 2


def _stored_key(
    url: str, datasets: tuple[str, ...], settings: tuple[str, ...], track: str
) -> tuple[Any, ...]:
    """What a stored snapshot must have been computed for to be served after a restart."""
    database = hashlib.sha256(url.encode()).hexdigest()[:16]  # never the URL itself: it may hold a password
    return (
        STORE_FORMAT,
        __version__,
        PHYSICS_VERSION,
        MATH_RULES_VERSION,
        SAMPLER_VERSION,
        database,
        datasets,
        settings,
        track,
    )


def stored_path(store_dir: Path, track: str) -> Path:
    return store_dir / f"boards-{track}.pickle"


def _snapshot_in_child(
    url: str, datasets: tuple[str, ...], settings: tuple[str, ...], track: str, store_dir: str | None = None
) -> tuple[tuple[Any, ...], list[bytes]]:
    """:func:`compute_snapshot` in the board process: the version it read and the snapshot, pickled in parts
    (each board, the grid) so the serving process unpickles one part at a time, never holding its GIL for
    the whole snapshot. Stored in ``store_dir`` too, for the next start (module docstring)."""
    from robobpp.db.session import is_sqlite, make_engine, make_session_factory

    factory = _CHILD_FACTORIES.get(url)
    if factory is None:
        factory = _CHILD_FACTORIES[url] = make_session_factory(make_engine(url, read_only=True, pool_size=1))
    with factory() as session, session.begin():
        if not is_sqlite(url):  # one snapshot of the database for the version and every row read
            session.connection(execution_options={"isolation_level": "REPEATABLE READ"})
        version = board_version(session, track)
        snap = compute_snapshot(session, datasets, settings, track)
    parts = [pickle.dumps((key, snap[key]), protocol=pickle.HIGHEST_PROTOCOL) for key in GRID_KEYS]
    parts += [pickle.dumps((key, b), protocol=pickle.HIGHEST_PROTOCOL) for key, b in snap["boards"].items()]
    if store_dir is not None:
        stored = {"key": _stored_key(url, datasets, settings, track), "version": version, "parts": parts}
        path = stored_path(Path(store_dir), track)
        try:
            partial = path.with_name(f".{path.name}.{os.getpid()}")
            partial.write_bytes(pickle.dumps(stored, protocol=pickle.HIGHEST_PROTOCOL))
            os.replace(partial, path)  # readers of the file see the old one or the new one, whole
        except OSError:
            log.exception("storing the %s boards in %s failed", track, store_dir)
    return version, parts


def _load_parts(parts: list[bytes]) -> dict[str, Any]:
    """A snapshot from its pickled parts, one part at a time (the request threads run between parts)."""
    snap: dict[str, Any] = {"boards": {}}
    for part in parts:
        key, value = pickle.loads(part)
        if key in GRID_KEYS:
            snap[key] = value
        else:
            snap["boards"][key] = value
        # part by part: the collector never gets to traverse a half-loaded snapshot either
        _out_of_the_collectors_reach()
        time.sleep(0)
    if any(key not in snap for key in GRID_KEYS):
        raise ValueError("a snapshot without its grids")
    return snap


def _out_of_the_collectors_reach() -> None:
    """Move what was just unpickled into the permanent generation (``gc.freeze``).

    A snapshot at 10,000 submissions is ~750,000 GC-tracked dicts and lists; every full collection of the
    cycle collector traverses all of them, a pause of ~0.6 s in which no request of the API process moves
    (BENCHMARKS.md). Boards hold no reference cycles (tests/server/test_scale.py), so frozen boards are
    still freed by reference counting once a newer snapshot replaces them. A young-generation collection
    first (milliseconds), so the short-lived garbage of request threads is not frozen with them; what
    cyclic garbage sits in the oldest generation at that moment is kept — a bounded amount per snapshot.
    """
    gc.collect(1)
    gc.freeze()


class _Slot:
    __slots__ = ("version", "value", "seconds", "refreshing")

    def __init__(self, version: tuple[Any, ...], value: Any, seconds: float) -> None:
        self.version, self.value, self.seconds, self.refreshing = version, value, seconds, False


class BoardCache:
    """Each track's snapshot (its boards and grid), and served bodies, stored with the track version they
    were computed at.

    ``datasets``/``settings`` are the boards a snapshot holds (a board outside them is computed on its own).
    ``database_url`` and ``process_from``: a track with at least ``process_from`` finished submissions is
    computed in a separate process (``_snapshot_in_child``), so the seconds of CPU it takes never hold the
    serving process's GIL; smaller tracks are computed in the calling thread. ``store_dir``: where the board
    process stores each snapshot, and :meth:`load_stored` finds them after a restart.
    """

    def __init__(
        self,
        session_factory: SessionFactory | None = None,
        *,
        size: int = 64,
        sync_limit_s: float = 0.25,
        refresh_s: float = 0.0,
        datasets: tuple[str, ...] = queries.DATASETS_ORDER,
        settings: tuple[str, ...] = queries.SETTINGS_ORDER,
        database_url: str | None = None,
        process_from: int | None = None,
        store_dir: Path | None = None,
    ) -> None:
        self._slots: dict[tuple[Any, ...], _Slot] = {}
        self._lock = threading.Lock()
        self._computing: dict[tuple[Any, ...], threading.Lock] = {}
        self.session_factory = session_factory
        self.size = size
        self.sync_limit_s = sync_limit_s
        self.refresh_s = refresh_s
        self.datasets, self.settings = tuple(datasets), tuple(settings)
        self.database_url = database_url
        self.process_from = process_from
        self.store_dir = store_dir
        self._pool: ProcessPoolExecutor | None = None
        self._versions: dict[str, tuple[float, tuple[Any, ...]]] = {}
        self._local = threading.local()  # the version of the data a body being built was read from
        self._responses: OrderedDict[tuple[Any, ...], tuple[tuple[Any, ...], bytes]] = OrderedDict()
        self.responses_size = 512
        #: Snapshots computed so far, and how long the last one took (``robobpp_board_*`` in /metrics).
        self.computed = 0
        self.last_seconds = 0.0
        #: Snapshots loaded from ``store_dir`` at start, and loaded there after another process computed them.
        self.loaded = 0
        self.shared = 0

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

    def fresh_response(self, track: str, key: tuple[Any, ...]) -> bytes | None:
        """The served body of ``key`` when it is current without asking SQL (the track's version was read
        less than ``refresh_s`` ago and the body was built at it), else None: then call :meth:`response`
        with a session. No I/O and no computation, so an async handler may call it on the event loop."""
        now = time.monotonic()
        with self._lock:
            known = self._versions.get(track)
            if known is None or now - known[0] >= self.refresh_s:
                return None
            hit = self._responses.get(key)
            if hit is None or hit[0] != known[1]:
                return None
            self._responses.move_to_end(key)
            return hit[1]

    def response(
        self, session: Session, track: str, key: tuple[Any, ...], build: Callable[[], bytes]
    ) -> bytes:
        """A served body (a page of a board as JSON, a rendered page) built once per board version: readers
        of the same page share it instead of each serialising or rendering it.

        A body is stored with the version of the data it was built from: while a large board is being
        recomputed it is built from the previous snapshot, and is served as such until the new one lands
        (never stored as if it were current)."""
        version = self.version(session, track)
        with self._lock:
            hit = self._responses.get(key)
            if hit is not None and (hit[0] == version or self._refreshing_at(track, hit[0])):
                self._responses.move_to_end(key)
                return hit[1]
        self._local.used = version
        body = build()
        used = self._local.used
        with self._lock:
            self._responses[key] = (used, body)
            while len(self._responses) > self.responses_size:
                self._responses.popitem(last=False)
        return body

    def _refreshing_at(self, track: str, version: tuple[Any, ...]) -> bool:
        """Whether the track's snapshot is still the one at ``version`` and its successor is being computed."""
        slot = self._slots.get(("snapshot", self.datasets, self.settings, track))
        return slot is not None and slot.refreshing and slot.version == version

    def snapshot(self, session: Session, track: str = "private") -> dict[str, Any]:
        """The track's boards and grid (:func:`compute_snapshot`), current as of its version."""
        version = self.version(session, track)
        key = ("snapshot", self.datasets, self.settings, track)
        return self._get(key, version, session, self._computer(key, version))

    def board(
        self, session: Session, dataset: str, setting: str, track: str = "private", protocol: str = CLOSED
    ) -> dict[str, Any]:
        """The full board (``robobpp.scoring.boards.build_board``); page it with ``board_view``. ``protocol``:
        ``closed`` (the benchmark) or ``paper`` (a physical setting's Math actions replayed)."""
        protocol = queries.board_protocol(setting, protocol)
        if dataset in self.datasets and setting in self.settings:
            boards = self.snapshot(session, track)["boards"]
            return boards[(dataset, setting) if protocol == CLOSED else (dataset, setting, protocol)]
        version, key = self.version(session, track), ("board", dataset, setting, protocol, track)
        return self._get(key, version, session, self._computer(key, version))

    def grid(
        self,
        session: Session,
        datasets: tuple[str, ...],
        settings: tuple[str, ...],
        track: str = "private",
        protocol: str = CLOSED,
    ) -> dict[str, Any]:
        """The overall grid (``protocol``: of its physical columns); page it with ``grid_view``."""
        grid_key = "grid" if protocol == CLOSED else f"grid-{protocol}"
        if tuple(datasets) == self.datasets and tuple(settings) == self.settings:
            return self.snapshot(session, track)[grid_key]
        version = self.version(session, track)
        key = ("grid", tuple(datasets), tuple(settings), protocol, track)
        return self._get(key, version, session, self._computer(key, version))

    def warm(self, tracks: tuple[str, ...] = ("private", "public")) -> None:
        """Compute the snapshots of large tracks now (the server calls this in a thread when it starts), so
        the first readers find them ready instead of waiting for them."""
        if self.session_factory is None:
            return
        for track in tracks:
            try:
                with self.session_factory() as session:
                    if self._in_board_process(self.version(session, track)):
                        self.snapshot(session, track)
            except Exception:  # noqa: BLE001 - the first reader computes it instead
                log.exception("warming the %s boards failed", track)

    def load_stored(self, tracks: tuple[str, ...] = ("private", "public")) -> None:
        """Serve the snapshots the board process stored before a restart until they are recomputed (the
        server calls this before it answers anyone; :meth:`warm` then recomputes them in the background)."""
        for track in tracks:
            stored = self._read_stored(track)
            if stored is None:
                continue
            try:
                snap = _load_parts(stored["parts"])
            except Exception:  # noqa: BLE001 - as a file that does not load
                log.warning("ignoring the stored %s boards: they do not load", track, exc_info=True)
                continue
            # never equal to a version read from SQL: the first read starts the recomputation, and bodies
            # built meanwhile are stored as built from this snapshot; as if it took forever to compute, so
            # readers never wait for its successor
            slot = _Slot(("stored", *stored["version"]), snap, math.inf)
            with self._lock:
                self._slots[("snapshot", self.datasets, self.settings, track)] = slot
                self.loaded += 1

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def _in_board_process(self, version: tuple[Any, ...]) -> bool:
        return (
            bool(self.database_url) and self.process_from is not None and int(version[0]) >= self.process_from
        )

    def _computer(
        self, key: tuple[Any, ...], version: tuple[Any, ...]
    ) -> Callable[[Session], tuple[Any, Any]]:
        """How to compute a slot's value (``key``: ``("snapshot" | "board" | "grid", …, track)``), as
        (version computed at or None, value); the first reader and the background refresh share it."""
        kind, track = key[0], key[-1]
        if kind == "board":
            return lambda s: (None, leaderboard(s, key[1], key[2], track=track, protocol=key[3]))
        if kind == "grid":
            grid_key = "grid" if key[3] == CLOSED else f"grid-{key[3]}"
            return lambda s: (None, compute_snapshot(s, key[1], key[2], track)[grid_key])
        return self._compute_snapshot(track, version)

    def _compute_snapshot(self, track: str, version: tuple[Any, ...]) -> Callable[[Session], tuple[Any, Any]]:
        """(version computed at or None, snapshot): in this thread, or in the board process."""
        if not self._in_board_process(version):
            return lambda s: (None, compute_snapshot(s, self.datasets, self.settings, track))

        def remote(_session: Session) -> tuple[Any, Any]:
            with self._lock:
                if self._pool is None:
                    # spawn, not fork: the serving process has threads and open connections
                    self._pool = ProcessPoolExecutor(
                        1, mp_context=multiprocessing.get_context("spawn"), max_tasks_per_child=1
                    )
                pool = self._pool
            assert self.database_url is not None
            with self._host_lock(track):
                # another API process of this host may have computed this very version while we waited
                stored = self._read_stored(track)
                if stored is not None and tuple(stored["version"]) == tuple(version):
                    snap = _load_parts(stored["parts"])
                    with self._lock:
                        self.shared += 1
                    return version, snap
                store = None if self.store_dir is None else str(self.store_dir)
                computed_at, parts = pool.submit(
                    _snapshot_in_child, self.database_url, self.datasets, self.settings, track, store
                ).result()
            return computed_at, _load_parts(parts)

        return remote

    @contextmanager
    def _host_lock(self, track: str) -> Iterator[None]:
        """Held while a track's snapshot is computed: the API processes of one host (``uvicorn --workers``)
        sharing ``store_dir`` compute each version once, the others load what it stored."""
        if self.store_dir is None or fcntl is None:
            yield
            return
        self.store_dir.mkdir(parents=True, exist_ok=True)
        with open(self.store_dir / f".boards-{track}.lock", "a+b") as handle:
            fcntl.flock(handle, fcntl.LOCK_EX)  # released with the file, or by the OS if the process dies
            try:
                yield
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)

    def _read_stored(self, track: str) -> dict[str, Any] | None:
        """The track's stored snapshot when it was written for these boards, this database and this version
        of robobpp, else None (a file that does not load is logged and ignored)."""
        if self.store_dir is None or not self.database_url:
            return None
        path = stored_path(self.store_dir, track)
        if not path.is_file():
            return None
        try:
            stored = pickle.loads(path.read_bytes())
            if stored["key"] != _stored_key(self.database_url, self.datasets, self.settings, track):
                log.info("ignoring %s: written for another version, database or set of boards", path)
                return None
            return stored
        except Exception:  # noqa: BLE001 - a damaged file costs a recomputation, never the start
            log.warning("ignoring %s: it does not load", path, exc_info=True)
            return None

    def _get(
        self,
        key: tuple[Any, ...],
        version: tuple[Any, ...],
        session: Session,
        compute: Callable[[Session], tuple[Any, Any]],
    ) -> Any:
        with self._lock:
            slot = self._slots.get(key)
            if slot is not None and slot.version == version:
                return slot.value
            if slot is not None and self.session_factory is not None and slot.seconds > self.sync_limit_s:
                self._local.used = slot.version  # a body built from it is stored under its version
                if not slot.refreshing:
                    slot.refreshing = True
                    threading.Thread(
                        target=self._refresh, args=(key,), daemon=True, name="board-refresh"
                    ).start()
                return slot.value
        return self._store(key, version, compute, session)

    def _store(
        self,
        key: tuple[Any, ...],
        version: tuple[Any, ...],
        compute: Callable[[Session], tuple[Any, Any]],
        session: Session,
    ) -> Any:
        with self._lock:
            key_lock = self._computing.setdefault(key, threading.Lock())
        with key_lock:  # readers arriving together wait for one computation instead of each doing it
            with self._lock:
                slot = self._slots.get(key)
                if slot is not None and slot.version == version:
                    return slot.value
            started = time.perf_counter()
            computed_at, value = compute(session)
            seconds = time.perf_counter() - started
            with self._lock:
                # the version the board process read (never older than ``version``): stored under it, a
                # submission that finished meanwhile is not computed twice
                self._slots[key] = _Slot(computed_at or version, value, seconds)
                while len(self._slots) > self.size:
                    self._slots.pop(next(iter(self._slots)))
                self.computed += 1
                self.last_seconds = seconds
            return value

    def _refresh(self, key: tuple[Any, ...]) -> None:
        assert self.session_factory is not None
        track = key[-1]
        try:
            with self.session_factory() as session:
                # the version read first: a submission finishing meanwhile makes the next read refresh again
                session.info.pop("board_versions", None)
                version = board_version(session, track)
                self._store(key, version, self._computer(key, version), session)
        except Exception:  # noqa: BLE001 - readers keep the previous board; the next stale read retries
            log.exception("board refresh failed for %s", key)
        finally:
            with self._lock:
                slot = self._slots.get(key)
                if slot is not None:
                    slot.refreshing = False
