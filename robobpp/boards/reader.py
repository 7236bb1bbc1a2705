"""An API process's reader of the published boards (:mod:`robobpp.boards.store`).

:class:`BoardCache` reads the publication row at most every ``refresh_s`` seconds
(``ROBOBPP_BOARD_REFRESH_S``) and caches parts and served bodies by board version, so a read costs no query
at all while nothing changed; a part never changes once written (a new version has new rows).

The publication is replaced in one transaction, so readers keep the previous version while the next is
computed, and a worker that dies mid-computation leaves it served. A restarted server serves the stored
boards at once. When the published boards are behind the data and their last publication was quick
(``wait_s``), a reader waits for the worker that long, so a small board shows a finished submission at
once, as it always did; a large one is served as it was until its successor lands.
"""

from __future__ import annotations

import json
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping
from typing import Any, cast

from sqlalchemy import select

from robobpp.boards import store
from robobpp.boards.ranking import participant_key
from robobpp.boards.store import (
    VERSION_PARTS,
    BoardsUnavailable,
    Publication,
    SessionFactory,
    StoredVersion,
    board_key,
    board_source,
    decode_version,
    grid_cell_keys,
    grid_key,
    published_lookaheads,
    read_publication,
    row_part,
    version_parts,
)
from robobpp.db.models import BoardPart
from robobpp.vocabulary import CLOSED, DATASETS, SETTINGS, board_loop

#: Locks a reader spreads its single-flight reads over (:class:`BoardCache`).
STRIPES = 32


class VersionGone(LookupError):
    """A part of a version the worker has since removed: read the publication again."""


class BoardCache:
    """An API process's reader of the published boards (module docstring).

    ``session_factory`` opens a short read transaction; the cache reads with its own, never a request's, so
    a version published after the request began is readable (SQLite's snapshot isolation). ``wake``: asks
    this process's board worker to look now (boards/worker.py), when it runs in this process.
    """

    def __init__(
        self,
        session_factory: SessionFactory,
        *,
        refresh_s: float = 0.0,
        wait_s: float = 2.0,
        datasets: tuple[str, ...] = DATASETS,
        settings: tuple[str, ...] = SETTINGS,
        wake: Callable[[], None] | None = None,
        parts_size: int = 4096,
        responses_size: int = 512,
    ) -> None:
        self.session_factory = session_factory
        self.refresh_s, self.wait_s = refresh_s, wait_s
        self.datasets, self.settings = tuple(datasets), tuple(settings)
        self.wake = wake
        self._lock = threading.Lock()
        self._publications: dict[str, tuple[float, Publication | None]] = {}
        #: One thread at a time reads a track's publication, decodes a board version or builds a served body:
        #: after a publication at 100,000 entries, twenty readers each decoding the same grid (and each asking
        #: SQL for the track's version) made a queue of hundreds of milliseconds. The others wait for that one
        #: (a decode, a body) or, for the publication, serve the one they know meanwhile. Striped by key;
        #: a build may take a decode's lock, never the reverse.
        self._reading: dict[str, threading.Lock] = {}
        self._decoding = tuple(threading.Lock() for _ in range(STRIPES))
        self._building = tuple(threading.Lock() for _ in range(STRIPES))
        self._parts: OrderedDict[tuple[Any, ...], Any] = OrderedDict()
        self.parts_size = parts_size
        self._responses: OrderedDict[tuple[Any, ...], tuple[int, bytes]] = OrderedDict()
        self.responses_size = responses_size
        #: Parts read from SQL so far, and times a reader waited for the worker (``robobpp_board_*``).
        self.parts_read = 0
        self.waited = 0

    # -- the publication --------------------------------------------------------------------------------

    def publication(self, track: str, *, force: bool = False) -> Publication | None:
        """The track's publication, read from SQL at most every ``refresh_s`` seconds per process. While one
        thread reads it, the others get the one read before (stale by at most that read's duration), unless
        there is none yet or ``force``: then they wait for it."""
        now = time.monotonic()
        with self._lock:
            known = self._publications.get(track)
            gate = self._reading.setdefault(track, threading.Lock())
        if not force and known is not None and now - known[0] < self.refresh_s:
            return known[1]
        if not gate.acquire(blocking=force or known is None or known[1] is None):
            return cast(tuple[float, Publication], known)[1]  # another thread is reading it
        try:
            with self._lock:
                again = self._publications.get(track)
            # read by the thread this one waited for (forced: one that began after this call, since the
            # version this caller knew is gone); a fresh server's readers waiting for its first publication
            # take the one read that waited for the worker, rather than each waiting ``wait_s`` in turn
            if again is not None and again is not known and (not force or again[0] >= now):
                return again[1]
            read_at = time.monotonic()
            with self.session_factory() as session:
                pub = read_publication(session, track)
                source = board_source(session, track, self.datasets, self.settings)
            if (pub is None or pub.source != source) and (pub is None or pub.seconds <= self.wait_s):
                pub = self._wait_for_worker(track, pub)
            with self._lock:
                self._publications[track] = (read_at, pub)
            return pub
        finally:
            gate.release()

    def _wait_for_worker(self, track: str, pub: Publication | None) -> Publication | None:
        """Behind the data and quick to publish: wait up to ``wait_s`` for the worker to catch up."""
        self.waited += 1
        if self.wake is not None:
            self.wake()
        deadline = time.monotonic() + self.wait_s
        while time.monotonic() < deadline:
            time.sleep(0.02)
            with self.session_factory() as session:
                pub = read_publication(session, track)
                if pub is not None and pub.source == board_source(
                    session, track, self.datasets, self.settings
                ):
                    break
        return pub

    def version(self, track: str, key: str | None) -> int:
        """The published version of board ``key`` (:func:`board_key`, :func:`grid_key`; None: the track's
        publication, which moves whenever any of its boards does)."""
        pub = self.publication(track)
        if pub is None:
            raise BoardsUnavailable(track)
        return pub.version if key is None else pub.board_version(key)

    # -- served bodies ----------------------------------------------------------------------------------

    def fresh_response(self, track: str, board: str | None, key: tuple[Any, ...]) -> bytes | None:
        """The served body of ``key`` when it is current without asking SQL (the publication was read less
        than ``refresh_s`` ago and the body was built from it), else None: then call :meth:`response`. No I/O,
        so an async handler may call it on the event loop."""
        now = time.monotonic()
        with self._lock:
            known = self._publications.get(track)
            gate = self._reading.get(track)
            if known is None or known[1] is None:
                return None
            if now - known[0] >= self.refresh_s and (gate is None or not gate.locked()):
                return None  # due for a read of the publication (one in flight: the known one serves)
            version = known[1].version if board is None else known[1].boards.get(board, (None,))[0]
            hit = self._responses.get(key)
            if hit is None or hit[0] != version:
                return None
            self._responses.move_to_end(key)
            return hit[1]

    def response(
        self, track: str, board: str | None, key: tuple[Any, ...], build: Callable[[], bytes]
    ) -> bytes:
        """A served body (a page of a board as JSON, a rendered page) built once per version of ``board``:
        readers of the same page share it instead of each serialising or rendering it."""
        for attempt in (0, 1):
            version = self.version(track, board)
            hit = self._response_of(key, version)
            if hit is not None:
                return hit
            with self._building[hash(key) % STRIPES]:  # readers of the same page wait for one build
                hit = self._response_of(key, version)
                if hit is not None:
                    return hit
                try:
                    body = build()
                except VersionGone:
                    if attempt:
                        raise
                    self.publication(track, force=True)
                    continue
                with self._lock:
                    self._responses[key] = (version, body)
                    while len(self._responses) > self.responses_size:
                        self._responses.popitem(last=False)
            return body
        raise AssertionError("unreachable")

    def _response_of(self, key: tuple[Any, ...], version: int) -> bytes | None:
        with self._lock:
            hit = self._responses.get(key)
            if hit is None or hit[0] != version:
                return None
            self._responses.move_to_end(key)
            return hit[1]

    # -- pages of a board -------------------------------------------------------------------------------

    def _fetch(self, track: str, key: str, wanted: Mapping[str, int], decode: bool = True) -> dict[str, Any]:
        """Parts by name, each of the version given (cached: a part never changes once written); raises
        :class:`VersionGone` when one is no longer stored. ``decode``: JSON parts decoded (else raw bytes)."""
        found: dict[str, Any] = {}
        with self._lock:
            for name, version in wanted.items():
                hit = self._parts.get((track, key, version, name))
                if hit is not None:
                    self._parts.move_to_end((track, key, version, name))
                    found[name] = hit
        missing = {name: version for name, version in wanted.items() if name not in found}
        if missing:
            with self.session_factory() as session:
                rows = session.execute(
                    select(BoardPart.part, BoardPart.version, BoardPart.body).where(
                        BoardPart.track == track,
                        BoardPart.board == key,
                        BoardPart.version.in_(set(missing.values())),
                        BoardPart.part.in_(list(missing)),
                    )
                ).all()
            got = {name: body for name, version, body in rows if missing.get(name) == version}
            if len(got) != len(missing):
                raise VersionGone(key)
            with self._lock:
                self.parts_read += len(got)
                for name, body in got.items():
                    value = json.loads(body) if decode else body
                    found[name] = self._parts[(track, key, missing[name], name)] = value
                while len(self._parts) > self.parts_size:
                    self._parts.popitem(last=False)
        return found

    def _stored(self, track: str, key: str) -> StoredVersion:
        """The published version of board ``key``, decoded (cached per version)."""
        version = self.version(track, key)
        hit = self._decoded(track, key, version)
        if hit is not None:
            return hit
        with self._decoding[hash((track, key)) % STRIPES]:  # its other readers wait for this decode
            hit = self._decoded(track, key, version)
            return hit if hit is not None else self._decode(track, key, version)

    def _decoded(self, track: str, key: str, version: int) -> StoredVersion | None:
        with self._lock:
            hit = self._parts.get((track, key, version, "#"))
            if hit is not None:
                self._parts.move_to_end((track, key, version, "#"))
            return cast(StoredVersion | None, hit)

    def _decode(self, track: str, key: str, version: int) -> StoredVersion:
        with self.session_factory() as session:
            parts = version_parts(session, track, key, version)
        if any(name not in parts for name in VERSION_PARTS):
            raise VersionGone(key)
        stored = decode_version(version, parts)
        with self._lock:
            self.parts_read += len(parts)
            # An older version of this board is read by no new request once this one is current: its decoded
            # order (ids, ranks, row versions: ≈ 2.5 MB at 50,000 entries) goes now, not when thousands of newer
            # parts have pushed it out of the LRU (the API's memory grew with every publication and N before).
            for old in [k for k in self._parts if k[3] == "#" and k[:2] == (track, key) and k[2] < version]:
                del self._parts[old]
            self._parts[(track, key, version, "#")] = stored
        return stored

    def _slice(self, track: str, key: str, name: str, total: int, offset: int, limit: int) -> list[Any]:
        stop = min(total, offset + limit)
        if offset >= stop:
            return []
        size = store.CHUNK  # read when used: a test writes and reads smaller chunks
        chunks = [f"{name}:{i}" for i in range(offset // size, (stop - 1) // size + 1)]
        held = self._stored(track, key).chunks
        read = self._fetch(track, key, {c: held[c] for c in chunks})
        items = [item for c in chunks for item in read[c]]
        start = offset - (offset // size) * size
        return items[start : start + (stop - offset)]

    def _all(self, track: str, key: str, total: int, offset: int, limit: int) -> list[Any]:
        """Entries (or grid rows) ``offset`` to ``offset + limit`` of the all-entries view: their ids, ranks
        and row versions from ``order``, each row of the version named, ranks put back."""
        stop = min(total, offset + limit)
        if offset >= stop:
            return []
        stored = self._stored(track, key)
        order = stored.order
        wanted = order.ids[offset:stop].tolist()
        rows = self._fetch(
            track,
            key,
            {row_part(sid): v for sid, v in zip(wanted, order.versions[offset:stop].tolist(), strict=True)},
        )
        out = []
        cells = order.cells
        cell_keys = grid_cell_keys(stored.head["head"]) if cells.shape[1] else []
        # a board's counts by participant (None: a grid, or a version stored before layout 3, whose rows
        # carry their own)
        submitted = None if cells.shape[1] else stored.head.get("submitted")
        for k, sid in enumerate(wanted):
            item = dict(rows[row_part(sid)])
            item["rank"] = int(order.ranks[offset + k])
            if submitted is not None:  # a board's row (the grid's have no count)
                item["entries_submitted"] = submitted[participant_key(item)]
            if cell_keys:
                item["cells"] = {
                    name: {**item["cells"][name], "rank": int(cells[offset + k, j])}
                    for j, name in enumerate(cell_keys)
                }
            out.append(item)
        return out

    def _head(self, track: str, key: str) -> dict[str, Any]:
        return self._stored(track, key).head

    def board_page(
        self,
        dataset: str,
        setting: str,
        track: str = "private",
        loop: str = CLOSED,
        view: str = "best",
        limit: int = 50,
        offset: int = 0,
        submission_id: int | None = None,
        lookahead: int = 0,
    ) -> dict[str, Any]:
        """One page of a board, as ``robobpp.boards.ranking.board_view`` pages the full board
        (``lookahead``: the board of the submissions that saw that many next boxes)."""
        key = board_key(dataset, setting, loop, lookahead)
        stored = self._head(track, key)
        counts = stored["counts"]
        if submission_id is None:
            entries = (
                self._all(track, key, counts["all"], offset, limit)
                if view == "all"
                else self._slice(track, key, view, counts[view], offset, limit)
            )
            unranked = self._slice(track, key, "unranked", counts["unranked"], 0, limit)
            total, unranked_total = counts[view], counts["unranked"]
        else:
            at = self._stored(track, key).locate(submission_id)
            entries = [] if at is None or at < 0 else self._all(track, key, counts["all"], at, 1)
            unranked = (
                []
                if at is None or at >= 0
                else self._slice(track, key, "unranked", counts["unranked"], -1 - at, 1)
            )
            total, unranked_total = len(entries), len(unranked)
        return {
            **stored["head"],
            "view": view,
            "total": total,
            "limit": limit,
            "offset": offset,
            "entries": entries,
            "unranked_total": unranked_total,
            "unranked": unranked,
            "column_tops": stored.get("tops", {}).get(view, {}),
        }

    def grid_page(
        self,
        track: str = "private",
        loop: str = CLOSED,
        view: str = "best",
        limit: int = 50,
        offset: int = 0,
        lookahead: int = 0,
    ) -> dict[str, Any]:
        """One page of the overall grid, as ``robobpp.boards.ranking.grid_view`` pages the full grid."""
        key = grid_key(loop, lookahead)
        stored = self._head(track, key)
        counts = stored["counts"]
        apart = f"apart-{view}"
        return {
            **stored["head"],
            "view": view,
            "total": counts[view],
            "limit": limit,
            "offset": offset,
            "rows": (
                self._all(track, key, counts["all"], offset, limit)
                if view == "all"
                else self._slice(track, key, view, counts[view], offset, limit)
            ),
            "apart_total": counts[apart],
            "apart": self._slice(track, key, apart, counts[apart], 0, limit),
            "column_tops": stored.get("tops", {}).get(view, {}),
        }

    def ranked_entry(
        self, dataset: str, setting: str, track: str, loop: str, submission_id: int, lookahead: int = 0
    ) -> tuple[dict[str, Any] | None, int]:
        """A submission's ranked entry on a board (as served) or None, and how many entries are ranked
        (``lookahead``: the submission's; a lookahead K > 0 has no paper-protocol boards: None, 0)."""
        if lookahead and board_loop(setting, loop) != CLOSED:
            return None, 0
        for attempt in (0, 1):
            try:
                page = self.board_page(dataset, setting, track, loop, "all", 1, 0, submission_id, lookahead)
                return (page["entries"][0] if page["entries"] else None), self._counts(
                    track, board_key(dataset, setting, loop, lookahead)
                )
            except VersionGone:
                if attempt:
                    raise
                self.publication(track, force=True)
        raise AssertionError("unreachable")

    def _counts(self, track: str, key: str) -> int:
        return int(self._head(track, key)["counts"]["all"])

    def lookaheads(self, track: str) -> list[int]:
        """The lookaheads the track's publication has boards of (0 and each K > 0 with entries)."""
        pub = self.publication(track)
        if pub is None:
            raise BoardsUnavailable(track)
        return published_lookaheads(pub.boards)
