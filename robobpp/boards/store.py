"""The published boards' stored format: what the board worker writes and every reader pages through.

A board (scores, bootstrap intervals, rank intervals) is costly to compute and changes only when a submission
of its track finishes. So it is computed by one board worker per deployment (:mod:`robobpp.boards.worker`)
and *published* in SQL, pre-serialised: per track one ``board_publications`` row names the current version
of each board, and ``board_parts`` holds each board version's parts — its head, its entries in chunks of
:data:`CHUNK` (each participant's best, the unranked ones), one row per entry of the all-entries view, and
its ``order`` (ids, ranks and the version holding each row; :class:`StoredBoard`). A reader
(:mod:`robobpp.boards.reader`) fetches the head and order, then the one or few chunks or rows a page
covers, by key. This module is the one both sides share: the worker writes with it, readers decode with
it, and neither imports the other (data flows engine → store → readers).
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any

import numpy as np
import orjson
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from robobpp import __version__
from robobpp.boards.ranking import participant_key, served_fields
from robobpp.boards.records import Board, Grid, Published, RankedView, Row
from robobpp.datasets.sampling import SAMPLER_VERSION
from robobpp.db.models import BoardPart, BoardPublication, Submission
from robobpp.scoring.scores import ANCHORS_VERSION, RESOLVED
from robobpp.sim.math_pack import MATH_RULES_VERSION
from robobpp.sim.physics.config import PHYSICS_VERSION
from robobpp.vocabulary import CLOSED, board_loop

log = logging.getLogger("robobpp.server")
SessionFactory = Callable[[], AbstractContextManager[Session]]
#: Entries per stored chunk: a page of up to 500 (the API's largest) reads at most 6 chunks.
CHUNK = 100
#: Bumped when the layout of the stored parts changes: a server of another layout recomputes them.
#: 3: an all-entries row without ``entries_submitted`` (the head's ``submitted`` gives it by participant).
#: 4: no ``index`` nor ``rows`` part (``order`` holds each row's version and hash); a chunk is written only
#: when its content changed (the head names the version holding each). 5: the head carries each view's column
#: tops (what its pages highlight). 6: boards per lookahead (a lookahead-0 board holds no other lookahead's
#: entries; every head names its ``lookahead`` and the track's ``lookaheads``).
LAYOUT = 6


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
    the scoring, the set of boards). A publication whose source differs is stale; after an upgrade the boards are
    recomputed once, and the old ones served meanwhile."""
    code = (
        LAYOUT,
        __version__,
        PHYSICS_VERSION,
        MATH_RULES_VERSION,
        SAMPLER_VERSION,
        ANCHORS_VERSION,  # the scores' rules: the stable anchors, Decision Time's resolution and least span
        sorted(RESOLVED.items()),
        *datasets,
        "|",
        *settings,
    )
    stamp = hashlib.sha256(repr(code).encode()).hexdigest()[:16]
    source: list[Any] = json.loads(to_json([*board_version(session, track), stamp]))
    return source


def board_key(dataset: str, setting: str, loop: str = CLOSED, lookahead: int = 0) -> str:
    """A board's key in the publication (a Math Pack board is one board under both protocols):
    ``repetitive/math/closed``; of a lookahead K > 0, ``repetitive/math/closed/lookahead-K``."""
    return f"{dataset}/{setting}/{board_loop(setting, loop)}" + _lookahead_part(lookahead)


def grid_key(loop: str = CLOSED, lookahead: int = 0) -> str:
    """A grid's key in the publication: ``grid/closed``, ``grid/paper``, ``grid/closed/lookahead-K``."""
    return f"grid/{loop}" + _lookahead_part(lookahead)


_LOOKAHEAD_PART = "/lookahead-"


def _lookahead_part(lookahead: int) -> str:
    return f"{_LOOKAHEAD_PART}{lookahead}" if lookahead else ""


def published_lookaheads(keys: Iterable[str]) -> list[int]:
    """The lookaheads a publication has boards of (its keys): 0 and each K > 0 with a grid."""
    return sorted(
        {0}
        | {
            int(k.rsplit(_LOOKAHEAD_PART, 1)[1])
            for k in keys
            if k.startswith("grid/") and _LOOKAHEAD_PART in k
        }
    )


# ----------------------------------------------------------------------------------------------------------
# The stored layout: what the worker writes and the readers page through


def _chunked(name: str, items: Sequence[Mapping[str, Any]]) -> dict[str, bytes]:
    return {f"{name}:{i // CHUNK}": to_json(list(items[i : i + CHUNK])) for i in range(0, len(items), CHUNK)}


def row_part(submission_id: int) -> str:
    """The part name of one entry's row of the all-entries view (``e:<submission id>``)."""
    return f"{ROW_PREFIX}{submission_id}"


#: Part names of the all-entries view's rows: one per entry, written only when its content changed.
ROW_PREFIX = "e:"


def row_hash(body: bytes) -> int:
    """A row's content as a signed 64-bit integer (what the next version compares against)."""
    return int.from_bytes(hashlib.blake2b(body, digest_size=8).digest(), "little", signed=True)


def chunk_hash(body: bytes) -> str:
    """A chunk's content, as the head names it (an unchanged chunk is not written again)."""
    return hashlib.blake2b(body, digest_size=8).hexdigest()


@dataclass(frozen=True)
class StoredRows:
    """The all-entries view's rows without ranks: ``ids`` ascending, ``build(i)`` the row of ``ids[i]``, and
    ``serials`` (the board engine's) a number per row that changes whenever the row does — the worker
    serialises a row again only then; None: every row is serialised."""

    ids: np.ndarray
    build: Callable[[int], Mapping[str, Any]]
    serials: np.ndarray | None = None

    def row(self, submission_id: int) -> Mapping[str, Any]:
        return self.build(int(np.searchsorted(self.ids, submission_id)))


@dataclass
class StoredBoard:
    """A board (or grid) version as the worker writes it (its parts are assembled in board_worker.py).

    ``head``: what every page repeats (with each list's length, and for a board its participants' entry
    counts and its unranked entries' ids). ``chunks``: the best view, the unranked entries (the grid's rows
    apart) in chunks of :data:`CHUNK` as served; a chunk whose content did not change stays where an earlier
    version wrote it. ``ids``, ``ranks``, ``cells``: the all-entries view in rank order (and the grid's cell
    ranks). ``rows``: that view's entries, each *without* its ranks (``"rank": null``, its cells' too): an
    arriving entry moves the rank of everyone below it and nothing else of theirs, so only the rows whose
    content changed are written (``e:<id>`` parts)."""

    head: dict[str, Any]
    chunks: dict[str, bytes]
    ids: np.ndarray
    ranks: np.ndarray
    cells: np.ndarray | None
    rows: StoredRows

    def digest(self, hashes: np.ndarray, ids: np.ndarray) -> str:
        """What the version holds (its parts and its rows' content): an unchanged one is not written."""
        h = hashlib.sha256(to_json(self.head))
        for name in sorted(self.chunks):
            h.update(name.encode() + b"\0" + hashlib.sha256(self.chunks[name]).digest())
        for array in (self.ids, self.ranks, self.cells, ids, hashes):
            if array is not None:
                h.update(np.ascontiguousarray(array, dtype=np.int64).tobytes())
        return h.hexdigest()[:32]


def order_part(
    ids: np.ndarray, ranks: np.ndarray, versions: np.ndarray, hashes: np.ndarray, cells: np.ndarray | None
) -> bytes:
    """The ``order`` part: the all-entries view in rank order — a header (entries, cell columns), then per
    entry its row's content hash (int64), submission id, rank and the version holding its row (int32), and
    the grid's cell ranks (int32, entries × columns). About 20 bytes an entry, rewritten with every version
    (an arriving entry moves the ranks below it); the rows themselves are written only when they change."""
    n, c = len(ids), 0 if cells is None else int(cells.shape[1])
    out = [np.array([n, c], dtype=np.int64), np.asarray(hashes, dtype=np.int64)]
    out += [np.asarray(a, dtype=np.int32) for a in (ids, ranks, versions)]
    if cells is not None:
        out.append(np.ascontiguousarray(cells, dtype=np.int32))
    return b"".join(a.tobytes() for a in out)


@dataclass(frozen=True)
class Order:
    """A decoded ``order`` part (rank order; int64 arrays)."""

    ids: np.ndarray
    ranks: np.ndarray
    versions: np.ndarray
    hashes: np.ndarray
    cells: np.ndarray

    @classmethod
    def decode(cls, body: bytes) -> Order:
        n, c = (int(x) for x in np.frombuffer(body, dtype=np.int64, count=2))
        hashes = np.frombuffer(body, dtype=np.int64, count=n, offset=16)
        small = np.frombuffer(body, dtype=np.int32, offset=16 + 8 * n).astype(np.int64)
        ids, ranks, versions = small[:n], small[n : 2 * n], small[2 * n : 3 * n]
        return cls(ids, ranks, versions, hashes, small[3 * n :].reshape(n, c))

    def by_id(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ids ascending, their row versions, their hashes): what the next version compares against."""
        at = np.argsort(self.ids, kind="stable")
        return self.ids[at], self.versions[at], self.hashes[at]


def _rankless(entry: Mapping[str, Any]) -> Mapping[str, Any]:
    """A served entry of the all-entries view as stored: without its rank and its participant's entry count
    (the engine's ``_base`` when it gave one). Each arriving entry moves the count of its participant's other
    entries, so it is stored once per board (the head's ``submitted``), not in each of their rows."""
    base: Mapping[str, Any] | None = entry.get("_base")
    if base is not None:
        return base
    row = {**served_fields(entry), "rank": None}
    row.pop("entries_submitted", None)
    return row


def board_parts(board: Board) -> StoredBoard:
    """A board as stored (:class:`StoredBoard`): chunks ``best:<i>`` and ``unranked:<i>``; a page of one
    submission finds it by the order's ids or the head's unranked ids."""
    lists = {
        "best": [served_fields(e) for e in board.best],
        "unranked": [dict(e) for e in board.unranked],
    }
    ids, ranks, rows = _all_entries(board.ranked, board.entries, _rankless)
    counts = {"best": len(lists["best"]), "all": len(ids), "unranked": len(lists["unranked"])}
    # every participant with a ranked entry has a best one, which carries their count
    submitted = {participant_key(e): e["entries_submitted"] for e in board.best}
    unranked = [e["submission_id"] for e in lists["unranked"]]
    chunks: dict[str, bytes] = {}
    for name, items in lists.items():
        chunks |= _chunked(name, items)
    head = {"head": board.head(), "counts": counts, "submitted": submitted, "unranked": unranked}
    head["tops"] = board.tops  # each view's column tops (what a page highlights)
    return StoredBoard(head, chunks, ids, ranks, None, rows)


def _all_entries(
    view: RankedView | None,
    entries: Sequence[Row],
    rankless: Callable[[Mapping[str, Any]], Mapping[str, Any]],
) -> tuple[np.ndarray, np.ndarray, StoredRows]:
    """The all-entries view's ids and ranks (rank order) and rows without ranks: from the board engine's
    arrays when it gave them (no ranked dict per entry, a row built only when it must be serialised), else
    from the entries."""
    if view is not None:
        return view.ids, view.ranks, StoredRows(view.ids_by_column, view.row, view.serials)
    ids = np.fromiter((e["submission_id"] for e in entries), dtype=np.int64, count=len(entries))
    ranks = np.fromiter((e["rank"] for e in entries), dtype=np.int64, count=len(entries))
    by_id = np.argsort(ids, kind="stable")
    return ids, ranks, StoredRows(ids[by_id], lambda i: rankless(entries[int(by_id[i])]))


def grid_cell_keys(head: Mapping[str, Any]) -> list[str]:
    """The grid's boards in the order of the stored cell ranks (:attr:`Grid.keys`), from its stored head."""
    return [f"{s}/{d}" for s in head["settings"] for d in head["datasets"]]


def _rankless_row(row: Mapping[str, Any]) -> Mapping[str, Any]:
    base: Mapping[str, Any] | None = row.get("_base")
    if base is not None:
        return base
    served = served_fields(row)
    cells = {k: {**c, "rank": None} for k, c in served["cells"].items()}
    return {**served, "rank": None, "cells": cells}


def grid_parts(grid: Grid) -> StoredBoard:
    """The overall grid as stored: chunks of ``best``, ``apart-best`` and ``apart-all`` (the rows of
    submissions not ranked on every board), and its ranked rows with their cell ranks (:class:`StoredBoard`)."""
    rows = grid.rows
    lists = {
        "best": [served_fields(r) for r in grid.best],
        "apart-best": [served_fields(r) for r in grid.best_apart],
        "apart-all": [served_fields(r) for r in grid.apart],
    }
    ids, ranks, stored = _all_entries(grid.ranked, rows, _rankless_row)
    counts = {k: len(v) for k, v in lists.items()} | {"all": len(ids)}
    chunks: dict[str, bytes] = {}
    for name, items in lists.items():
        chunks |= _chunked(name, items)
    view = grid.ranked
    if view is not None and view.cells is not None:
        cells = view.cells
    else:
        keys = grid.keys
        cells = np.array([[r["cells"][k]["rank"] for k in keys] for r in rows], dtype=np.int64).reshape(
            len(rows), len(keys)
        )
    head_part = {"head": grid.head(), "counts": counts, "tops": grid.tops}
    return StoredBoard(head_part, chunks, ids, ranks, cells, stored)


def parts_of(item: Published) -> StoredBoard:
    """A board or grid as stored."""
    return grid_parts(item) if isinstance(item, Grid) else board_parts(item)


@dataclass(frozen=True)
class StoredVersion:
    """A board version as a reader decoded it: its head, the version holding each chunk, the all-entries
    view's order and where each submission is (``locate``: ids ascending, and for each its position ``i`` in
    the ranked view or ``-1 - i`` among the unranked)."""

    head: dict[str, Any]
    chunks: dict[str, int]
    order: Order
    located_ids: np.ndarray
    located_at: np.ndarray

    def locate(self, submission_id: int) -> int | None:
        i = int(np.searchsorted(self.located_ids, submission_id))
        if i < len(self.located_ids) and self.located_ids[i] == submission_id:
            return int(self.located_at[i])
        return None


def _located(ids: np.ndarray, unranked: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    every = np.concatenate([ids, np.asarray(unranked, dtype=np.int64)])
    at = np.concatenate([np.arange(len(ids)), -1 - np.arange(len(unranked))])
    by = np.argsort(every, kind="stable")
    return every[by], at[by]


def decode_version(version: int, parts: Mapping[str, bytes]) -> StoredVersion:
    """A board version from its ``head`` and ``order`` parts — or, stored by layout 3 (an upgrade's
    publication, served until the upgraded worker replaces it), from its ``head``, ``order``, ``rows`` and
    ``index``, every chunk at the version itself."""
    head = json.loads(parts["head"])
    if "parts" in head:  # layout 4 and later
        order = Order.decode(parts["order"])
        chunks = {name: int(at[0]) for name, at in head["parts"].items()}
        located = _located(order.ids, head.get("unranked", ()))
        return StoredVersion(head, chunks, order, *located)
    body = parts["order"]
    n, c = (int(x) for x in np.frombuffer(body, dtype=np.int64, count=2))
    arrays = np.frombuffer(body, dtype=np.int64, offset=16)
    ids, ranks = arrays[:n], arrays[n : 2 * n]
    m = int(np.frombuffer(parts["rows"], dtype=np.int64, count=1)[0])
    manifest = np.frombuffer(parts["rows"], dtype=np.int64, offset=8)
    at = np.searchsorted(manifest[:m], ids)
    order = Order(
        ids, ranks, manifest[m : 2 * m][at], manifest[2 * m : 3 * m][at], arrays[2 * n :].reshape(n, c)
    )
    k = len(parts.get("index", b"")) // 16
    index = np.frombuffer(parts.get("index", b""), dtype=np.int64)
    counts = head["counts"]
    chunks = {
        f"{name}:{i}": version
        for name, total in counts.items()
        if name != "all"
        for i in range((total + CHUNK - 1) // CHUNK)
    }
    return StoredVersion(head, chunks, order, index[:k], index[k:])


#: What a reader reads of a version to decode it (a layout-3 version: also ``rows`` and ``index``).
VERSION_PARTS = ("head", "order")
LEGACY_PARTS = ("rows", "index")


def version_parts(session: Session, track: str, key: str, version: int) -> dict[str, bytes]:
    """The parts of a board version that :func:`decode_version` reads, by name (those stored)."""
    rows = session.execute(
        select(BoardPart.part, BoardPart.body).where(
            BoardPart.track == track,
            BoardPart.board == key,
            BoardPart.version == version,
            BoardPart.part.in_(VERSION_PARTS + LEGACY_PARTS),
        )
    ).all()
    return {name: body for name, body in rows}


# ----------------------------------------------------------------------------------------------------------
# The publication row


class BoardsUnavailable(LookupError):
    """The board was never published (a fresh server's worker has not finished its first computation, or
    the board is not one this server publishes)."""


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
