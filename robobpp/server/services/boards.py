"""Leaderboards published as data: one board worker computes them, every API process reads them by index.

A board (scores, bootstrap intervals, rank intervals) is costly to compute and changes only when a submission
of its track finishes. So it is computed by one board worker per deployment (services/board_worker.py) and
*published* in SQL, pre-serialised: per track one ``board_publications`` row names the current version of
each board, and ``board_parts`` holds each board version's parts — its head, its entries in chunks of
:data:`CHUNK` per view (each participant's best, every entry, the unranked ones) and an index from
submission id to position. A reader fetches the head and the one or few chunks a page covers, by key.

:class:`BoardCache` is an API process's reader. It reads the publication row at most every ``refresh_s``
seconds (``ROBOBPP_BOARD_REFRESH_S``) and caches parts and served bodies by board version, so a read costs
no query at all while nothing changed; a part never changes once written (a new version has new rows).

The publication is replaced in one transaction, so readers keep the previous version while the next is
computed, and a worker that dies mid-computation leaves it served. A restarted server serves the stored
boards at once. When the published boards are behind the data and their last publication was quick
(``wait_s``), a reader waits for the worker that long, so a small board shows a finished submission at
once, as it always did; a large one is served as it was until its successor lands.
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any

import numpy as np
import orjson
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from robobpp import __version__
from robobpp.datasets.sampling import SAMPLER_VERSION
from robobpp.db import queries
from robobpp.db.models import BoardPart, BoardPublication, Submission
from robobpp.replay import CLOSED, PAPER
from robobpp.scoring.boards import _served, participant_key
from robobpp.sim.math_pack import MATH_RULES_VERSION
from robobpp.sim.physics.config import PHYSICS_VERSION

log = logging.getLogger("robobpp.server")
SessionFactory = Callable[[], AbstractContextManager[Session]]
#: Entries per stored chunk: a page of up to 500 (the API's largest) reads at most 6 chunks.
CHUNK = 100
#: Bumped when the layout of the stored parts changes: a server of another layout recomputes them.
#: 3: an all-entries row without ``entries_submitted`` (the head's ``submitted`` gives it by participant).
LAYOUT = 3


def board_version(session: Session, track: str) -> tuple[Any, ...]:
    """Changes whenever a submission of ``track`` (or, for ``private``, a verification) finishes or is
    removed (ix_submissions_track_finished), and for ``private`` when a verification starts."""
    version = tuple(
        session.execute(
            select(func.count(), func.max(Submission.finished_at)).where(
                # a verification finishing writes its verdict onto a private entry (db/verification.py)
                Submission.track.in_((track, "verify") if track == "private" else (track,)),
                Submission.finished_at.is_not(None),
            )
        ).one()
    )
    if track == "private":  # a verification starting shows "pending" on its entry at once
        version += (session.execute(select(func.count()).where(Submission.track == "verify")).scalar_one(),)
    return version


def to_json(data: Any) -> bytes:
    """Compact JSON, a UTC time with ``Z`` (orjson: a published board's rows and pages, 13× faster than the
    json module, the same values; a float under 1e-4 is written without an exponent; ``bench/bench_serialise.py``).
    A non-finite float, which no stored figure is, becomes null."""
    return orjson.dumps(data, option=orjson.OPT_UTC_Z | orjson.OPT_NON_STR_KEYS)


def board_source(session: Session, track: str, datasets: Sequence[str], settings: Sequence[str]) -> list[Any]:
    """What published boards were computed from: the data's version and the code's (the rules, the sampler,
    the set of boards). A publication whose source differs is stale; after an upgrade the boards are
    recomputed once, and the old ones served meanwhile."""
    code = (
        LAYOUT,
        __version__,
        PHYSICS_VERSION,
        MATH_RULES_VERSION,
        SAMPLER_VERSION,
        *datasets,
        "|",
        *settings,
    )
    stamp = hashlib.sha256(repr(code).encode()).hexdigest()[:16]
    return json.loads(to_json([*board_version(session, track), stamp]))


def board_key(dataset: str, setting: str, protocol: str = CLOSED) -> str:
    """A board's key in the publication (a Math Pack board is one board under both protocols)."""
    return f"{dataset}/{setting}/{queries.board_protocol(setting, protocol)}"


def grid_key(protocol: str = CLOSED) -> str:
    return f"grid/{protocol}"


def published_key(key: tuple[str, ...] | str) -> str:
    """A board engine's key (``(dataset, setting)``, ``(dataset, setting, "paper")``, ``"grid"``,
    ``"grid-paper"``: services/board_engine.py) as published."""
    if isinstance(key, str):
        return grid_key(PAPER if key.endswith(PAPER) else CLOSED)
    return board_key(*key)


# ----------------------------------------------------------------------------------------------------------
# The stored layout: what the worker writes and the readers page through


def _chunked(name: str, items: Sequence[Mapping[str, Any]]) -> dict[str, bytes]:
    return {f"{name}:{i // CHUNK}": to_json(list(items[i : i + CHUNK])) for i in range(0, len(items), CHUNK)}


def _index(positions: Mapping[int, int]) -> bytes:
    """Submission id -> position, as two int64 arrays sorted by id (looked up by binary search)."""
    ids = np.fromiter(positions.keys(), dtype=np.int64, count=len(positions))
    where = np.fromiter(positions.values(), dtype=np.int64, count=len(positions))
    order = np.argsort(ids, kind="stable")
    return ids[order].tobytes() + where[order].tobytes()


def row_part(submission_id: int) -> str:
    """The part name of one entry's row of the all-entries view (``e:<submission id>``)."""
    return f"{ROW_PREFIX}{submission_id}"


#: Part names of the all-entries view's rows: one per entry, written only when its content changed.
ROW_PREFIX = "e:"


def row_hash(body: bytes) -> int:
    """A row's content as a signed 64-bit integer (the ``rows`` manifest's hash)."""
    return int.from_bytes(hashlib.blake2b(body, digest_size=8).digest(), "little", signed=True)


@dataclass
class StoredBoard:
    """A board (or grid) version as the worker writes it.

    ``parts``: what is written whole with every version — ``head``, the chunks of the best view and of the
    unranked entries, ``index`` (submission id -> position) and ``order`` (the all-entries view: its
    submission ids in rank order, their ranks, and for the grid each cell's rank). ``rows``: the
    all-entries view's entries by submission id, each *without* its ranks (``"rank": null``, its cells'
    too): an arriving entry moves the rank of everyone below it and nothing else of theirs, so only the rows
    whose content changed are written (``e:<id>`` parts, services/board_worker.py). A row's value is the
    served dict, or a dict handed out by the board engine that stays the same object while its content does
    (``_base``): the worker serialises each such object once."""

    parts: dict[str, bytes]
    rows: dict[int, Mapping[str, Any]]

    def digest(self, hashes: np.ndarray, ids: np.ndarray) -> str:
        """What the version holds (its parts and its rows' content): an unchanged one is not written."""
        h = hashlib.sha256()
        for name in sorted(self.parts):
            h.update(name.encode() + b"\0" + hashlib.sha256(self.parts[name]).digest())
        h.update(ids.tobytes() + hashes.tobytes())
        return h.hexdigest()[:32]


def _order(ids: Sequence[int], ranks: Sequence[int], cells: np.ndarray | None = None) -> bytes:
    """The all-entries view's order: a header (entries, cell columns), ids, ranks, cell ranks (entries × columns)."""
    n, c = len(ids), 0 if cells is None else int(cells.shape[1])
    out = np.array([n, c], dtype=np.int64).tobytes()
    out += np.asarray(ids, dtype=np.int64).tobytes() + np.asarray(ranks, dtype=np.int64).tobytes()
    return out + (b"" if cells is None else np.ascontiguousarray(cells, dtype=np.int64).tobytes())


def _rankless(entry: Mapping[str, Any]) -> Mapping[str, Any]:
    """A served entry of the all-entries view as stored: without its rank and its participant's entry count
    (the engine's ``_base`` when it gave one). Each arriving entry moves the count of its participant's other
    entries, so it is stored once per board (the head's ``submitted``), not in each of their rows."""
    base = entry.get("_base")
    if base is not None:
        return base
    row = {**_served(entry), "rank": None}
    row.pop("entries_submitted", None)
    return row


def board_parts(board: Mapping[str, Any]) -> StoredBoard:
    """A board (``robobpp.scoring.boards.build_board``) as stored: ``head`` (what every page of it repeats,
    and each list's length), ``best:<i>``, ``unranked:<i>`` (chunks of entries as served), ``order`` and
    ``index`` (a submission's ranked position ``i`` in ``all``, or ``-1 - i`` in ``unranked``), and a row
    per entry of the all-entries view (:class:`StoredBoard`)."""
    entries = board["entries"]
    lists = {"best": [_served(e) for e in board["_best"]], "unranked": [dict(e) for e in board["unranked"]]}
    head = {k: v for k, v in board.items() if not k.startswith("_") and k not in ("entries", "unranked")}
    counts = {"best": len(lists["best"]), "all": len(entries), "unranked": len(lists["unranked"])}
    # every participant with a ranked entry has a best one, which carries their count
    submitted = {participant_key(e): e["entries_submitted"] for e in board["_best"]}
    parts = {"head": to_json({"head": head, "counts": counts, "submitted": submitted})}
    for name, items in lists.items():
        parts |= _chunked(name, items)
    ids = [e["submission_id"] for e in entries]
    parts["order"] = _order(ids, [e["rank"] for e in entries])
    positions = {sid: i for i, sid in enumerate(ids)}
    positions |= {e["submission_id"]: -1 - i for i, e in enumerate(lists["unranked"])}
    parts["index"] = _index(positions)
    return StoredBoard(parts, {e["submission_id"]: _rankless(e) for e in entries})


def grid_cell_keys(head: Mapping[str, Any]) -> list[str]:
    """The grid's boards in the order of the stored cell ranks (as ``build_grid`` orders them)."""
    return [f"{s}/{d}" for s in head["settings"] for d in head["datasets"]]


def _rankless_row(row: Mapping[str, Any]) -> Mapping[str, Any]:
    base = row.get("_base")
    if base is not None:
        return base
    served = _served(row)
    cells = {k: {**c, "rank": None} for k, c in served["cells"].items()}
    return {**served, "rank": None, "cells": cells}


def grid_parts(grid: Mapping[str, Any]) -> StoredBoard:
    """The overall grid as stored: ``head``, chunks of ``best``, ``apart-best`` and ``apart-all`` (the rows
    of submissions not ranked on every board), ``order`` (with each ranked row's cell ranks) and a row per
    ranked submission (:class:`StoredBoard`)."""
    rows = grid["rows"]
    lists = {
        "best": [_served(r) for r in grid["_best"]],
        "apart-best": [_served(r) for r in grid["_best_apart"]],
        "apart-all": [_served(r) for r in grid["apart"]],
    }
    head = {k: v for k, v in grid.items() if k not in ("rows", "apart") and not k.startswith("_")}
    counts = {k: len(v) for k, v in lists.items()} | {"all": len(rows)}
    parts = {"head": to_json({"head": head, "counts": counts})}
    for name, items in lists.items():
        parts |= _chunked(name, items)
    keys = grid_cell_keys(grid)
    cells = np.array([[r["cells"][k]["rank"] for k in keys] for r in rows], dtype=np.int64).reshape(
        len(rows), len(keys)
    )
    parts["order"] = _order([r["submission_id"] for r in rows], [r["rank"] for r in rows], cells)
    return StoredBoard(parts, {r["submission_id"]: _rankless_row(r) for r in rows})


def parts_of(key: str, value: Mapping[str, Any]) -> StoredBoard:
    return grid_parts(value) if key.startswith("grid/") else board_parts(value)


# ----------------------------------------------------------------------------------------------------------
# Reading


class BoardsUnavailable(LookupError):
    """The board was never published (a fresh server's worker has not finished its first computation, or
    the board is not one this server publishes)."""


class _Gone(LookupError):
    """A part of a version the worker has since removed: read the publication again."""


@dataclass(frozen=True)
class Publication:
    """A track's publication row as a reader saw it."""

    version: int
    source: list[Any] | None
    boards: dict[str, Any]
    seconds: float

    def board_version(self, key: str) -> int:
        entry = self.boards.get(key)
        if entry is None:
            raise BoardsUnavailable(key)
        return int(entry[0])


def read_publication(session: Session, track: str) -> Publication | None:
    row = session.get(BoardPublication, track)
    if row is None:
        return None
    return Publication(row.version, row.source, dict(row.boards or {}), float(row.seconds or 0.0))


class BoardCache:
    """An API process's reader of the published boards (module docstring).

    ``session_factory`` opens a short read transaction; the cache reads with its own, never a request's, so
    a version published after the request began is readable (SQLite's snapshot isolation). ``wake``: asks
    this process's board worker to look now (services/board_worker.py), when it runs in this process.
    """

    def __init__(
        self,
        session_factory: SessionFactory,
        *,
        refresh_s: float = 0.0,
        wait_s: float = 2.0,
        datasets: tuple[str, ...] = queries.DATASETS_ORDER,
        settings: tuple[str, ...] = queries.SETTINGS_ORDER,
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
        self._parts: OrderedDict[tuple[Any, ...], Any] = OrderedDict()
        self.parts_size = parts_size
        self._responses: OrderedDict[tuple[Any, ...], tuple[int, bytes]] = OrderedDict()
        self.responses_size = responses_size
        #: Parts read from SQL so far, and times a reader waited for the worker (``robobpp_board_*``).
        self.parts_read = 0
        self.waited = 0

    # -- the publication --------------------------------------------------------------------------------

    def publication(self, track: str, *, force: bool = False) -> Publication | None:
        """The track's publication, read from SQL at most every ``refresh_s`` seconds per process."""
        now = time.monotonic()
        with self._lock:
            known = self._publications.get(track)
        if not force and known is not None and now - known[0] < self.refresh_s:
            return known[1]
        with self.session_factory() as session:
            pub = read_publication(session, track)
            source = board_source(session, track, self.datasets, self.settings)
        if (pub is None or pub.source != source) and (pub is None or pub.seconds <= self.wait_s):
            pub = self._wait_for_worker(track, pub)
        with self._lock:
            self._publications[track] = (now, pub)
        return pub

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
            if known is None or known[1] is None or now - known[0] >= self.refresh_s:
                return None
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
            with self._lock:
                hit = self._responses.get(key)
                if hit is not None and hit[0] == version:
                    self._responses.move_to_end(key)
                    return hit[1]
            try:
                body = build()
            except _Gone:
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

    # -- pages of a board -------------------------------------------------------------------------------

    def _read(self, track: str, key: str, names: Sequence[str]) -> dict[str, Any]:
        """Parts of the published version of board ``key``, decoded (``index``: its two arrays)."""
        version = self.version(track, key)
        found: dict[str, Any] = {}
        with self._lock:
            for name in names:
                hit = self._parts.get((track, key, version, name))
                if hit is not None:
                    self._parts.move_to_end((track, key, version, name))
                    found[name] = hit
        missing = [n for n in names if n not in found]
        if missing:
            with self.session_factory() as session:
                rows = session.execute(
                    select(BoardPart.part, BoardPart.body).where(
                        BoardPart.track == track,
                        BoardPart.board == key,
                        BoardPart.version == version,
                        BoardPart.part.in_(missing),
                    )
                ).all()
            if len(rows) != len(missing):
                raise _Gone(key)
            with self._lock:
                self.parts_read += len(rows)
                for name, body in rows:
                    found[name] = self._parts[(track, key, version, name)] = _decode(name, body)
                while len(self._parts) > self.parts_size:
                    self._parts.popitem(last=False)
        return found

    def _slice(self, track: str, key: str, name: str, total: int, offset: int, limit: int) -> list[Any]:
        stop = min(total, offset + limit)
        if offset >= stop:
            return []
        chunks = [f"{name}:{i}" for i in range(offset // CHUNK, (stop - 1) // CHUNK + 1)]
        read = self._read(track, key, chunks)
        items = [item for c in chunks for item in read[c]]
        start = offset - (offset // CHUNK) * CHUNK
        return items[start : start + (stop - offset)]

    def _all(self, track: str, key: str, total: int, offset: int, limit: int) -> list[Any]:
        """Entries (or grid rows) ``offset`` to ``offset + limit`` of the all-entries view: their ids and
        ranks from ``order``, each row of the version the ``rows`` manifest names, ranks put back."""
        stop = min(total, offset + limit)
        if offset >= stop:
            return []
        stored = self._read(track, key, ["order", "rows"])
        ids, ranks, cells = stored["order"]
        manifest_ids, versions = stored["rows"]
        wanted = ids[offset:stop]
        at = np.searchsorted(manifest_ids, wanted)
        rows = self._rows(track, key, wanted.tolist(), versions[at].tolist())
        out = []
        cell_keys = grid_cell_keys(self._head(track, key)["head"]) if cells.shape[1] else []
        # a board's counts by participant (None: a grid, or a version stored before layout 3, whose rows
        # carry their own, served by an upgraded server until its first publication replaces them)
        submitted = None if cells.shape[1] else self._head(track, key).get("submitted")
        for k, sid in enumerate(wanted.tolist()):
            item = dict(rows[sid])
            item["rank"] = int(ranks[offset + k])
            if submitted is not None:  # a board's row (the grid's have no count)
                item["entries_submitted"] = submitted[participant_key(item)]
            if cell_keys:
                item["cells"] = {
                    name: {**item["cells"][name], "rank": int(cells[offset + k, j])}
                    for j, name in enumerate(cell_keys)
                }
            out.append(item)
        return out

    def _rows(self, track: str, key: str, ids: list[int], versions: list[int]) -> dict[int, Any]:
        """Rows of the all-entries view by submission id, each of the version given (cached: a row never
        changes once written)."""
        found: dict[int, Any] = {}
        with self._lock:
            for sid, version in zip(ids, versions, strict=True):
                hit = self._parts.get((track, key, version, row_part(sid)))
                if hit is not None:
                    found[sid] = hit
        missing = {
            row_part(sid): version for sid, version in zip(ids, versions, strict=True) if sid not in found
        }
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
            got = {(name, version): body for name, version, body in rows if missing.get(name) == version}
            if len(got) != len(missing):
                raise _Gone(key)
            with self._lock:
                self.parts_read += len(got)
                for (name, version), body in got.items():
                    sid = int(name[len(ROW_PREFIX) :])
                    found[sid] = self._parts[(track, key, version, name)] = json.loads(body)
                while len(self._parts) > self.parts_size:
                    self._parts.popitem(last=False)
        return found

    def _head(self, track: str, key: str) -> dict[str, Any]:
        head: dict[str, Any] = self._read(track, key, ["head"])["head"]
        return head

    def board_page(
        self,
        dataset: str,
        setting: str,
        track: str = "private",
        protocol: str = CLOSED,
        view: str = "best",
        limit: int = 50,
        offset: int = 0,
        submission_id: int | None = None,
    ) -> dict[str, Any]:
        """One page of a board, as ``robobpp.scoring.boards.board_view`` pages the full board."""
        key = board_key(dataset, setting, protocol)
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
            at = self._locate(track, key, submission_id)
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
        }

    def grid_page(
        self,
        track: str = "private",
        protocol: str = CLOSED,
        view: str = "best",
        limit: int = 50,
        offset: int = 0,
    ) -> dict[str, Any]:
        """One page of the overall grid, as ``robobpp.scoring.boards.grid_view`` pages the full grid."""
        key = grid_key(protocol)
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
        }

    def _locate(self, track: str, key: str, submission_id: int) -> int | None:
        ids, where = self._read(track, key, ["index"])["index"]
        i = int(np.searchsorted(ids, submission_id))
        return int(where[i]) if i < len(ids) and ids[i] == submission_id else None

    def ranked_entry(
        self, dataset: str, setting: str, track: str, protocol: str, submission_id: int
    ) -> tuple[dict[str, Any] | None, int]:
        """A submission's ranked entry on a board (as served) or None, and how many entries are ranked."""
        for attempt in (0, 1):
            try:
                page = self.board_page(dataset, setting, track, protocol, "all", 1, 0, submission_id)
                return (page["entries"][0] if page["entries"] else None), self._counts(
                    track, dataset, setting, protocol
                )
            except _Gone:
                if attempt:
                    raise
                self.publication(track, force=True)
        raise AssertionError("unreachable")

    def _counts(self, track: str, dataset: str, setting: str, protocol: str) -> int:
        return int(self._head(track, board_key(dataset, setting, protocol))["counts"]["all"])


def _decode(name: str, body: bytes) -> Any:
    if name == "index":
        n = len(body) // 16
        return np.frombuffer(body[: 8 * n], dtype=np.int64), np.frombuffer(body[8 * n :], dtype=np.int64)
    if name == "order":
        n, c = (int(x) for x in np.frombuffer(body, dtype=np.int64, count=2))
        arrays = np.frombuffer(body, dtype=np.int64, offset=16)
        return arrays[:n], arrays[n : 2 * n], arrays[2 * n :].reshape(n, c)
    if name == "rows":
        ids, versions, _hashes = manifest_of(body)
        return ids, versions
    return json.loads(body)


def manifest(ids: np.ndarray, versions: np.ndarray, hashes: np.ndarray) -> bytes:
    """The ``rows`` part: which version of each entry's row a board version shows (ids ascending), and the
    rows' content hashes (what the next version compares against)."""
    return (
        np.array([len(ids)], dtype=np.int64).tobytes()
        + ids.astype(np.int64).tobytes()
        + versions.astype(np.int64).tobytes()
        + hashes.astype(np.int64).tobytes()
    )


def manifest_of(body: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = int(np.frombuffer(body, dtype=np.int64, count=1)[0])
    arrays = np.frombuffer(body, dtype=np.int64, offset=8)
    return arrays[:n], arrays[n : 2 * n], arrays[2 * n : 3 * n]
