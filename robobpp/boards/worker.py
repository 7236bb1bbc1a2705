"""The board worker: computes a track's boards when its data changed and publishes them in SQL.

One per deployment computes: every candidate (one beside each ``robobpp serve``) polls the cheap
``board_source`` of each track, and the one that sees it move *claims* the track's publication row (a lease,
``holder``/``lease_until``, renewed while it computes) before computing; the others leave it alone. A
worker that dies mid-computation stops renewing, its claim lapses after ``lease_s`` and another worker takes
over; until then, and meanwhile, the previous version stays published. The new version is written in one
transaction that also checks the claim is still held, so a worker that stalled past its lease publishes
nothing.

Boards whose serialised parts did not change (a Math Pack submission leaves the physical boards as they were)
keep their parts; only changed boards get a new version. Each board keeps its previous version's parts too,
so a reader that read the publication just before it moved still finds what it named.

Modes (``ROBOBPP_BOARD_WORKER``): ``process`` (a spawned process beside the API process: the seconds of
scoring never hold the API's interpreter lock), ``thread`` (a thread of the API process: small deployments,
tests) or ``off`` (another process or host runs it).
"""

from __future__ import annotations

import functools
import logging
import math
import multiprocessing
import os
import signal
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta
from typing import Any, Protocol, cast

import numpy as np
from sqlalchemy import CursorResult, Table, Update, delete, or_, tuple_, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from robobpp import logs
from robobpp.boards.engine import BoardEngine, board_of, grid_of, trim_heap
from robobpp.boards.records import Published
from robobpp.boards.store import (
    LAYOUT,
    ROW_PREFIX,
    VERSION_PARTS,
    SessionFactory,
    StoredBoard,
    board_key,
    board_source,
    chunk_hash,
    decode_version,
    grid_key,
    order_part,
    parts_of,
    read_publication,
    row_hash,
    row_part,
    to_json,
    version_parts,
)
from robobpp.db.models import BoardPart, BoardPublication, utcnow
from robobpp.scoring import kernels
from robobpp.vocabulary import BOARD_TRACKS
from robobpp.worker.lifeline import Lifeline

log = logging.getLogger("robobpp.server")


def published_key(key: tuple[str, ...] | str) -> str:
    """A board engine's key (:func:`robobpp.boards.engine.board_id`, :func:`~robobpp.boards.engine.grid_id`) as published."""
    if isinstance(key, str):
        return grid_key(*grid_of(key))
    return board_key(*board_of(key))


class Engine(Protocol):
    """What the publisher needs of a board engine (boards/engine.py)."""

    def keys(self, track: str) -> list[tuple[str, ...] | str]:
        """Every board and grid the track has now (a lookahead's come and go with its entries)."""
        ...

    def update(self, track: str) -> Mapping[tuple[str, ...] | str, Published]: ...

    def refresh(self, track: str) -> Mapping[tuple[str, ...] | str, Published]: ...


class BoardPublisher:
    """Claims, computes and publishes one track at a time (module docstring). ``read``: a read-only
    transaction (the computation; never a writer's lock on SQLite); ``write``: a transaction that commits.
    ``engine``: computes the boards that changed (default: a ``BoardEngine`` reading through ``read``)."""

    def __init__(
        self,
        read: SessionFactory,
        write: SessionFactory,
        datasets: tuple[str, ...],
        settings: tuple[str, ...],
        *,
        engine: Engine | None = None,
        lease_s: float = 30.0,
        holder: str | None = None,
    ) -> None:
        self.read, self.write = read, write
        self.datasets, self.settings = tuple(datasets), tuple(settings)
        self._given = engine
        self.engine = self._new_engine()
        self.lease_s = lease_s
        self.holder = holder or f"{socket.gethostname()[:40]}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        #: Computations and publications so far, and the wall time of the last publication.
        self.computed = self.published = 0
        self.last_seconds = 0.0
        #: CPU seconds of this process for the last computation and publication (its lease thread included).
        self.last_cpu_seconds = 0.0
        #: Per published board: its rows' ids (ascending), serials and hashes (an engine's row keeps its serial
        #: while its content stays: serialised once), and what its published version holds
        #: (:class:`_Held`) to compare the next one against.
        self._hashes: dict[tuple[str, str], tuple[np.ndarray, np.ndarray | None, np.ndarray]] = {}
        self._held: dict[tuple[str, str], _Held] = {}
        #: Rows written by the last publication (its boards together), for the benchmark and the tests.
        self.rows_written = 0

    def _new_engine(self) -> Engine:
        return self._given or BoardEngine(self.read, self.datasets, self.settings)

    def publish(self, track: str, *, full: bool = False, force: bool = False) -> bool:
        """Compute and publish ``track`` when its data (or the code) changed since its last publication (or
        ``force``) and no other worker holds it; ``full``: every board in full (``BoardEngine.refresh``: the
        all-entries rank intervals too, which an update leaves as they were). True when a new version was
        published."""
        with self.read() as session:
            pub = read_publication(session, track)
            if not force and pub is not None and pub.source == self._source(session, track):
                return False
        if pub is None:
            self._create(track)
        elif pub.source is None:  # asked to recompute everything (request_recompute)
            self.engine = self._new_engine()
        if not self._claim(track):
            return False
        started, cpu = time.perf_counter(), time.process_time()
        try:
            with self._renewing(track):
                with self.read() as session:  # read first: the boards are never older than what it names
                    source = self._source(session, track)
                computed = self.engine.refresh(track) if full else self.engine.update(track)
                self.computed += 1
                boards = {published_key(k): v for k, v in computed.items()}
                # each board serialised as it is written, not all first: a first publication serialises
                # every row, and every board's bodies at once were gigabytes at 100,000 submissions
                stored = {
                    key: functools.partial(self._stored, track, key, value) for key, value in boards.items()
                }
            known = set(map(published_key, self.engine.keys(track)))
            computed_s = time.perf_counter() - started
            published = self._write(track, source, stored, known, computed_s)
            trim_heap()  # the rows' bodies are gone: the heap they took goes back to the system
            self.last_cpu_seconds = time.process_time() - cpu
            log.info(
                "the %s boards took %.2f s of CPU in this process; computed in %.2f s, written in %.2f s",
                track,
                self.last_cpu_seconds,
                computed_s,
                time.perf_counter() - started - computed_s,
            )
            return published
        finally:
            self._release(track)

    def _source(self, session: Session, track: str) -> list[Any]:
        return board_source(session, track, self.datasets, self.settings)

    def _create(self, track: str) -> None:
        try:
            with self.write() as session:
                session.add(BoardPublication(track=track, version=0, boards={}, seconds=0.0))
        except IntegrityError:  # another worker created it first
            pass

    def _claim(self, track: str) -> bool:
        now = utcnow()
        with self.write() as session:
            claimed = _matched(
                session,
                update(BoardPublication)
                .where(
                    BoardPublication.track == track,
                    or_(
                        BoardPublication.holder.is_(None),
                        BoardPublication.holder == self.holder,
                        BoardPublication.lease_until < now,
                    ),
                )
                .values(holder=self.holder, lease_until=now + timedelta(seconds=self.lease_s)),
            )
        return bool(claimed)

    def _renew(self, track: str) -> bool:
        with self.write() as session:
            return bool(
                _matched(
                    session,
                    update(BoardPublication)
                    .where(BoardPublication.track == track, BoardPublication.holder == self.holder)
                    .values(lease_until=utcnow() + timedelta(seconds=self.lease_s)),
                )
            )

    def _release(self, track: str) -> None:
        try:
            with self.write() as session:
                session.execute(
                    update(BoardPublication)
                    .where(BoardPublication.track == track, BoardPublication.holder == self.holder)
                    .values(holder=None, lease_until=None)
                )
        except Exception:
            log.warning("releasing the %s boards' lease failed", track, exc_info=True)

    @contextmanager
    def _renewing(self, track: str) -> Iterator[None]:
        """Renew the claim every third of the lease while the body runs."""
        done = threading.Event()

        def renew() -> None:
            while not done.wait(self.lease_s / 3):
                try:
                    if not self._renew(track):
                        log.warning("lost the %s boards' lease while computing them", track)
                        return
                except Exception:
                    log.warning("renewing the %s boards' lease failed", track, exc_info=True)

        beat = threading.Thread(target=renew, daemon=True, name="board-lease")
        beat.start()
        try:
            yield
        finally:
            done.set()
            beat.join()

    def _stored(self, track: str, key: str, board: Published) -> _Hashed:
        return self._rows_hashed(track, key, parts_of(board))

    def _rows_hashed(self, track: str, key: str, stored: StoredBoard) -> _Hashed:
        """The board's rows with their content hashes; a row whose serial is the one it had at the last
        publication keeps its hash (it is serialised again only if it must be written)."""
        rows = stored.rows
        ids, serials = rows.ids, rows.serials
        hashes = np.empty(len(ids), dtype=np.int64)
        hit = np.zeros(len(ids), dtype=bool)
        k_ids, k_serials, k_hashes = self._hashes.get((track, key), (ids[:0], None, hashes[:0]))
        if serials is not None and k_serials is not None and len(k_ids):
            at = np.minimum(np.searchsorted(k_ids, ids), len(k_ids) - 1)
            hit = (k_ids[at] == ids) & (k_serials[at] == serials)
            hashes[hit] = k_hashes[at[hit]]
        bodies: dict[int, bytes] = {}
        for i in np.flatnonzero(~hit).tolist():
            body = to_json(rows.build(i))
            hashes[i] = row_hash(body)
            bodies[int(ids[i])] = body
        self._hashes[(track, key)] = (ids, serials, hashes)
        return _Hashed(stored, ids, hashes, bodies)

    def _held_by(self, session: Session, track: str, key: str, version: int) -> _Held:
        """What a published board version holds (kept from the last publication, or read)."""
        kept = self._held.get((track, key))
        if kept is not None and kept.version == version:
            return kept
        parts = version_parts(session, track, key, version)
        if any(name not in parts for name in VERSION_PARTS):
            return _Held.empty(version)
        stored = decode_version(version, parts)
        head_parts = stored.head.get("parts", {})  # a layout-3 version: no chunk is reused
        chunks = {name: (int(at[0]), str(at[1])) for name, at in head_parts.items()}
        return _Held(version, *stored.order.by_id(), chunks)

    def _write(
        self,
        track: str,
        source: list[Any],
        stored: Mapping[str, Callable[[], _Hashed]],
        known: set[str],
        seconds: float,
    ) -> bool:
        """Publish in one transaction: for each board whose content changed, its head and order under the new
        version, and only the chunks and rows whose content changed; what the previous version shows is
        kept (a reader may just have named it), older parts removed. ``stored``: each board's serialised
        parts, made when that board is written (one board's bodies in memory at a time)."""
        written = 0
        held: dict[tuple[str, str], _Held] = {}
        table = cast(Table, BoardPart.__table__)
        with self.write() as session:
            row = session.get(BoardPublication, track, with_for_update=True, populate_existing=True)
            if row is None or row.holder != self.holder:
                log.warning("not publishing the %s boards: another worker holds them now", track)
                return False
            version = row.version + 1
            before: dict[str, Any] = dict(row.boards or {})
            after = {key: entry for key, entry in before.items() if key in known}  # the engine's unchanged
            changed = False
            for key, serialised in stored.items():
                hashed = serialised()
                board = hashed.board
                sha = board.digest(hashed.hashes, hashed.ids)
                old = before.get(key)
                if old is not None and old[1] == sha:
                    after[key] = old
                    continue
                changed = True
                ids, hashes = hashed.ids, hashed.hashes
                prev = self._held_by(session, track, key, int(old[0])) if old is not None else _Held.empty(0)
                found, same, p_row_versions = _against(ids, hashes, prev.ids, prev.versions, prev.hashes)
                versions = np.where(same, p_row_versions, version)
                fresh = ids[~same].tolist()
                values = []
                chunks: dict[str, tuple[int, str]] = {}
                for name, body in board.chunks.items():
                    digest = chunk_hash(body)
                    kept = prev.chunks.get(name)
                    if kept is not None and kept[1] == digest:
                        chunks[name] = kept
                    else:
                        chunks[name] = (version, digest)
                        values.append({"part": name, "body": body})
                head = {**board.head, "layout": LAYOUT, "parts": chunks}
                at = np.searchsorted(ids, board.ids)  # the rows in rank order
                values.append({"part": "head", "body": to_json(head)})
                values.append(
                    {
                        "part": "order",
                        "body": order_part(board.ids, board.ranks, versions[at], hashes[at], board.cells),
                    }
                )
                values += ({"part": row_part(sid), "body": hashed.body(sid)} for sid in fresh)
                session.connection().execute(  # executemany of Core rows: no ORM objects for thousands of rows
                    table.insert().values(track=track, board=key, version=version), values
                )
                written += len(fresh)
                after[key] = [version, sha]
                held[(track, key)] = _Held(version, ids, versions, hashes, chunks)
                if old is None:
                    continue
                # older than the previous version and shown by neither it nor the new one: removed (a reader
                # may just have named the previous version)
                shown = {(name, v) for name, (v, _) in (*prev.chunks.items(), *chunks.items()) if v < old[0]}
                session.execute(
                    delete(BoardPart).where(
                        BoardPart.track == track,
                        BoardPart.board == key,
                        BoardPart.version < old[0],
                        BoardPart.part.not_like(f"{ROW_PREFIX}%"),
                        *([tuple_(BoardPart.part, BoardPart.version).not_in(shown)] if shown else []),
                    )
                )
                # a row replaced now: the one the previous version shows stays, older ones go — one
                # statement per version shown and chunk of parts (a few in all), not one per row
                replaced = found & ~same
                for shown_at in np.unique(p_row_versions[replaced]).tolist():
                    parts = [row_part(int(sid)) for sid in ids[replaced & (p_row_versions == shown_at)]]
                    for start in range(0, len(parts), _DELETE_CHUNK):
                        session.connection().execute(
                            delete(table).where(
                                table.c.track == track,
                                table.c.board == key,
                                table.c.version < shown_at,
                                table.c.part.in_(parts[start : start + _DELETE_CHUNK]),
                            )
                        )
            for key in before.keys() - known:  # boards this server no longer publishes
                changed = True
                session.execute(delete(BoardPart).where(BoardPart.track == track, BoardPart.board == key))
            if changed:
                row.version, row.boards = version, after
            row.source, row.seconds, row.published_at = source, seconds, utcnow()
        self._held.update(held)
        self.published += 1
        self.last_seconds = seconds
        self.rows_written = written
        log.info(
            "published the %s boards (version %d) in %.2f s, %d entry rows written",
            track,
            row.version,
            seconds,
            written,
        )
        return changed


#: Parts named per delete statement (SQLite allows 32,766 bound values in one; PostgreSQL 65,535).
_DELETE_CHUNK = 1000


def _against(
    ids: np.ndarray, hashes: np.ndarray, p_ids: np.ndarray, p_versions: np.ndarray, p_hashes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each row (ids ascending) against the previous manifest: whether it was there, whether its content is
    the same, and the version of its row there (0 when absent)."""
    if len(p_ids) == 0:
        none = np.zeros(len(ids), dtype=bool)
        return none, none, np.zeros(len(ids), dtype=np.int64)
    at = np.minimum(np.searchsorted(p_ids, ids), len(p_ids) - 1)
    found = p_ids[at] == ids
    return found, found & (p_hashes[at] == hashes), np.where(found, p_versions[at], 0)


@dataclass(frozen=True)
class _Held:
    """What a published board version holds: its rows (ids ascending, the version holding each, their
    content hashes) and its chunks (name -> the version holding it, its content hash)."""

    version: int
    ids: np.ndarray
    versions: np.ndarray
    hashes: np.ndarray
    chunks: dict[str, tuple[int, str]]

    @classmethod
    def empty(cls, version: int) -> _Held:
        none = np.zeros(0, dtype=np.int64)
        return cls(version, none, none, none, {})


@dataclass
class _Hashed:
    """A board version to publish with its rows' hashes (ids ascending) and the bodies serialised so far."""

    board: StoredBoard
    ids: np.ndarray
    hashes: np.ndarray
    bodies: dict[int, bytes]

    def body(self, submission_id: int) -> bytes:
        body = self.bodies.get(submission_id)
        return body if body is not None else to_json(self.board.rows.row(submission_id))


def request_recompute(session: Session, track: str | None = None) -> int:
    """Ask the board worker to recompute ``track`` (every track when None) although nothing changed; the
    published boards stay served until it has (``robobpp db refresh-boards``). Returns the rows marked."""
    where = [] if track is None else [BoardPublication.track == track]
    return _matched(session, update(BoardPublication).where(*where).values(source=None))


def _matched(session: Session, statement: Update) -> int:
    """The rows an UPDATE matched (``Session.execute`` is typed as returning a plain ``Result``)."""
    return cast(CursorResult[Any], session.execute(statement)).rowcount


def await_first_publication(
    read: SessionFactory, timeout_s: float, tracks: tuple[str, ...] = BOARD_TRACKS
) -> bool:
    """Wait (at most ``timeout_s``) until every track has been published once: a server starting on a
    database that has none (a fresh one, or the first start after migration 0011) answers its first readers
    with boards rather than 503. A server restarted on published boards returns at once."""
    deadline = time.monotonic() + timeout_s
    while True:
        with read() as session:
            published = [read_publication(session, t) for t in tracks]
        if all(pub is not None and pub.boards for pub in published):
            return True
        if time.monotonic() > deadline:
            log.warning("the boards are not published yet: their routes answer 503 until they are")
            return False
        time.sleep(0.1)


#: The largest share of the worker's time its timed full computations may take: one is due ``full_s`` after
#: the last, and no sooner than its duration / FULL_SHARE. A full computation takes a minute at 10,000
#: submissions but 18 at 100,000; every 300 s there, the worker would be computing in full most of the time,
#: and a finished submission waits for the pass in progress before its update (BENCHMARKS.md).
FULL_SHARE = 0.1


class BoardWorker:
    """Publishes every track whenever it changed: polls every ``poll_s`` seconds, or at once when woken; and
    every ``full_s`` seconds (or ten times as long as the last one took, :data:`FULL_SHARE`) recomputes each
    track in full (``BoardEngine.refresh``). A track whose full computation took under ``cheap_s`` is always
    computed in full (every rank interval current at once)."""

    def __init__(
        self,
        publisher: BoardPublisher,
        *,
        poll_s: float = 0.5,
        full_s: float = 300.0,
        cheap_s: float = 1.0,
        tracks: tuple[str, ...] = BOARD_TRACKS,
    ) -> None:
        self.publisher, self.poll_s, self.full_s, self.tracks = publisher, poll_s, full_s, tracks
        self.cheap_s = cheap_s
        self._last_full = dict.fromkeys(tracks, -math.inf)
        self._full_cost = dict.fromkeys(tracks, 0.0)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def run_once(self) -> list[str]:
        """One pass over the tracks: those published."""
        published = []
        for track in self.tracks:
            started, computed = time.monotonic(), self.publisher.computed
            due = started - self._last_full[track] >= max(self.full_s, self._full_cost[track] / FULL_SHARE)
            full = due or self._full_cost[track] < self.cheap_s
            try:
                if self.publisher.publish(track, full=full, force=due):
                    published.append(track)
                if full and self.publisher.computed > computed:
                    self._last_full[track] = time.monotonic()
                    self._full_cost[track] = self._last_full[track] - started
            except Exception:
                log.exception("computing the %s boards failed", track)
        return published

    def run(self, alive: Callable[[], bool] = lambda: True) -> None:
        if not kernels.BUILT:  # in a thread of the server or a process of its own, said once as it starts
            log.warning(
                "robobpp.scoring._kernels is not built (installed without a C compiler): boards are computed "
                "by numpy alone, a full computation taking about half again as long"
            )
        while not self._stop.is_set() and alive():
            self._wake.clear()
            self.run_once()
            self._wake.wait(self.poll_s)

    def wake(self) -> None:
        self._wake.set()

    def start(self) -> None:
        self._thread = threading.Thread(target=self.run, daemon=True, name="board-worker")
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=30)


def worker_for_url(
    url: str, datasets: tuple[str, ...], settings: tuple[str, ...], **kwargs: Any
) -> BoardWorker:
    """A worker with its own connections to ``url``."""
    from robobpp.db.session import make_engine, make_session_factory, transaction

    reads = make_session_factory(make_engine(url, read_only=True, pool_size=2))
    writes = make_session_factory(make_engine(url, pool_size=2))

    @contextmanager
    def read() -> Iterator[Session]:
        with reads() as session, session.begin():
            yield session

    publisher = BoardPublisher(read, lambda: transaction(writes), datasets, settings)
    return BoardWorker(publisher, **kwargs)


def _process_main(
    url: str,
    datasets: tuple[str, ...],
    settings: tuple[str, ...],
    timing: dict[str, float],
    stop: Any,
    lifeline: Lifeline,
) -> None:
    """The board worker process. It ends with the process that started it however that ends, even in the middle
    of a computation (``lifeline``, worker/lifeline.py): an API process killed outright (SIGKILL, the OOM killer)
    once left its worker computing to the end of its pass — at 100,000 submissions a full one is 18 minutes and
    14 GB — and renewing its claim on the track, so a restarted server's worker waited that long to claim it.
    Nothing is lost: an unfinished publication is never committed."""
    # Ctrl-C at a terminal reaches the whole process group: the server stops us through ``stop`` (a
    # KeyboardInterrupt here printed its traceback under the server's clean shutdown)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    lifeline.hold("board worker")
    logs.configure()
    worker = worker_for_url(url, datasets, settings, **timing)
    # ends when asked, or with the API process however it ends; a SIGTERM (to the whole process group, say)
    # ends it at once: a publication cut short leaves the previous boards served and its lease to lapse
    worker.run(alive=lambda: not stop.value and lifeline.intact())


#: How long a stopping server waits for its board worker process to finish a pass before ending it.
STOP_GRACE_S = 5.0


class WorkerProcess:
    """The board worker in a spawned process (``ROBOBPP_BOARD_WORKER=process``)."""

    def __init__(
        self, url: str, datasets: tuple[str, ...], settings: tuple[str, ...], **timing: float
    ) -> None:
        context = multiprocessing.get_context("spawn")  # the API process has threads and open connections
        # A flag in shared memory, not an Event: setting an Event waits for its sleeping waiters to wake, and
        # one killed by a signal to the process group never does (the server then hung on shutdown).
        self._stop = context.Value("b", 0, lock=False)
        self.process = context.Process(
            target=_process_main,
            args=(url, tuple(datasets), tuple(settings), timing, self._stop, Lifeline.to_here()),
            daemon=True,
            name="robobpp-board-worker",
        )

    def start(self) -> None:
        self.process.start()

    def wake(self) -> None:  # it polls on its own
        pass

    def stop(self) -> None:
        """Asks it to stop after its current pass (it polls the flag between passes); a long computation is
        cut short after ``STOP_GRACE_S``."""
        self._stop.value = 1
        self.process.join(timeout=STOP_GRACE_S)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout=5)
