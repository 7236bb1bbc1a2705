"""One board entry's own part of the scoring, computed once when its run finishes and stored with it.

Everything here depends on the run alone — its per-group figures, the resample plan (a function of the
group count only, :func:`robobpp.scoring.stats.resample_counts`) and the fixed stable anchors — so no other
entry arriving or leaving can change it. A board update then only does the global part (min–max per
resample, ranks: :mod:`robobpp.boards.matrix`).

Stored form (``runs.entry``, :meth:`EntryPart.encode`): a small header, then little-endian arrays — the group
ids, the per-group figures as two groups × metrics float32 matrices (what a resample sums: the value, 0 when
unmeasured, or a pooled ratio's numerator; and its weight: 1 measured / 0 not, or the denominator), each
metric's interval and the stable score's, and the seed of its timing noise
(:func:`robobpp.scoring.stats.timing_seed`). float32: every resample reads the figures so
(:func:`robobpp.scoring.stats.as_resampled`), so a board built from them equals one built from the recorded
JSON figures. Decoding is a view of the bytes (no copy, no parsing); a board's start decodes its parts
together (:class:`StoredParts`: parts of one layout read as one array of records), 10,000 in milliseconds.
"""

from __future__ import annotations

import dataclasses
import struct
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from robobpp.scoring import stats
from robobpp.scoring.metrics import POOLED
from robobpp.scoring.scores import RESOLVED, WEIGHTS, add_timing_noise, anchored

#: Bumped when the stored layout or what it holds changes; a part of another format is recomputed.
#: 3: the timing noise's seed; the stable interval with Decision Time under anchors-v2 and timing noise.
#: 4: the figures as float32, as every resample reads them.
FORMAT = 4
_HEADER = struct.Struct("<4sHHHH")  # magic, format, groups, metrics, resamples / 1 (0 = the default)
_MAGIC = b"RBPE"


def stored_format(data: bytes) -> int | None:
    """The format a stored part was written in (None: not a part)."""
    if len(data) < _HEADER.size:
        return None
    magic, fmt, *_ = _HEADER.unpack_from(data)
    return int(fmt) if magic == _MAGIC else None


@cache
def metric_keys(setting: str) -> tuple[str, ...]:
    """The scored metrics of a setting, in the order of its weights (the order scores sum them)."""
    return tuple(WEIGHTS[setting])


@cache
def counts(groups: int) -> np.ndarray:
    """The shared resample plan of a board of ``groups`` groups (read-only: every board shares it)."""
    plan = stats.resample_counts(groups)
    plan.flags.writeable = False
    return plan


@dataclass(frozen=True, slots=True)
class EntryPart:
    """A run's figures as a matrix and the intervals that depend on it alone."""

    setting: str
    ids: np.ndarray  # (groups,) int64, ascending
    top: (
        np.ndarray
    )  # (groups, metrics) float32: per-group sum terms (value, or pooled numerator; 0 unmeasured)
    bottom: (
        np.ndarray
    )  # (groups, metrics) float32: per-group weights (1 measured / 0 not, or pooled denominator)
    metric_ci: np.ndarray  # (metrics, 2), NaN = no interval
    stable_ci: tuple[float, float]
    seed: int = 0  # of its timing noise: stats.timing_seed of its per-group Decision Times

    @property
    def groups(self) -> int:
        return int(self.ids.shape[0])

    def encode(self) -> bytes:
        m = len(metric_keys(self.setting))
        return b"".join(
            (
                _HEADER.pack(_MAGIC, FORMAT, self.groups, m, 0),
                self.ids.astype("<i8").tobytes(),
                self.top.astype("<f4").tobytes(),
                self.bottom.astype("<f4").tobytes(),
                self.metric_ci.astype("<f8").tobytes(),
                np.array(self.stable_ci, dtype="<f8").tobytes(),
                np.array([self.seed], dtype="<u8").tobytes(),
            )
        )

    @classmethod
    def decode(cls, data: bytes, setting: str) -> EntryPart | None:
        """The part stored in ``data``, or None when it is of another format or setting (recompute it).
        The arrays are read-only views of ``data``: decoding copies nothing."""
        if len(data) < _HEADER.size:
            return None
        magic, fmt, groups, m, _ = _HEADER.unpack_from(data)
        if magic != _MAGIC or fmt != FORMAT or m != len(metric_keys(setting)):
            return None
        at = _HEADER.size
        ids = np.frombuffer(data, "<i8", groups, at)
        at += 8 * groups
        top = np.frombuffer(data, "<f4", groups * m, at).reshape(groups, m)
        at += 4 * groups * m
        bottom = np.frombuffer(data, "<f4", groups * m, at).reshape(groups, m)
        at += 4 * groups * m
        metric_ci = np.frombuffer(data, "<f8", 2 * m, at).reshape(m, 2)
        at += 16 * m
        stable_ci = np.frombuffer(data, "<f8", 2, at)
        seed = int(np.frombuffer(data, "<u8", 1, at + 16)[0])
        return cls(setting, ids, top, bottom, metric_ci, (float(stable_ci[0]), float(stable_ci[1])), seed)


def _layout(groups: int, metrics: int) -> np.dtype:
    """One stored part of ``groups`` groups and ``metrics`` metrics as a numpy record (:meth:`EntryPart.encode`'s
    layout): parts of the same header decode many at once (:meth:`StoredParts.decode`)."""
    return np.dtype(
        [
            ("header", f"V{_HEADER.size}"),
            ("ids", "<i8", (groups,)),
            ("top", "<f4", (groups, metrics)),
            ("bottom", "<f4", (groups, metrics)),
            ("metric_ci", "<f8", (metrics, 2)),
            ("stable_ci", "<f8", (2,)),
            ("seed", "<u8"),
        ]
    )


@dataclass(frozen=True, slots=True)
class PartRows:
    """Entries' parts of one group-id list as arrays, a row per entry (:class:`EntryPart`'s fields stacked):
    what :meth:`StoredParts.decode` makes of many stored parts at once, kept by a :class:`PartTable` without
    an object per entry."""

    submission_ids: np.ndarray  # (entries,) int64
    ids: np.ndarray  # (groups,) int64: the group ids every row shares
    top: np.ndarray  # (entries, groups, metrics) float32
    bottom: np.ndarray  # (entries, groups, metrics) float32
    metric_ci: np.ndarray  # (entries, metrics, 2)
    stable_ci: np.ndarray  # (entries, 2)
    seeds: np.ndarray  # (entries,) uint64

    def taken(self, chosen: np.ndarray) -> PartRows:
        """The rows ``chosen`` (a mask or indices), as rows of their own."""
        return PartRows(
            self.submission_ids[chosen],
            self.ids,
            self.top[chosen],
            self.bottom[chosen],
            self.metric_ci[chosen],
            self.stable_ci[chosen],
            self.seeds[chosen],
        )

    def part(self, row: int, setting: str) -> EntryPart:
        stable = self.stable_ci[row]
        return EntryPart(
            setting,
            self.ids,
            self.top[row],
            self.bottom[row],
            self.metric_ci[row],
            (float(stable[0]), float(stable[1])),
            int(self.seeds[row]),
        )


class StoredParts(Mapping[int, "EntryPart | None"]):
    """Entries' parts by submission id, decoded from their stored bytes many at a time (:meth:`decode`).

    A board's start reads 10,000 stored parts; one :class:`EntryPart` each (six array views and an object)
    and then stacking them again into the board's matrices took ≈ 0.3 s a board (BENCHMARKS.md, "The board
    engine"), where parts of the same layout read as one array of records take milliseconds. Rows of one
    group-id list stay together as :class:`PartRows`, which :meth:`PartTable.put_many` keeps as they are; a
    part set one at a time (:meth:`set`: computed from a run's figures, or None: the run has none) sits beside
    them. As a mapping, an entry's :class:`EntryPart` is made when asked for."""

    def __init__(self, setting: str) -> None:
        self.setting = setting
        self.rows: list[PartRows] = []
        self.single: dict[int, EntryPart | None] = {}
        self._at: dict[int, tuple[int, int]] = {}  # submission id -> (its rows, its row)

    @classmethod
    def decode(
        cls, setting: str, submission_ids: Sequence[int], data: Sequence[bytes | None]
    ) -> tuple[StoredParts, list[int]]:
        """The parts stored in ``data`` (an entry's bytes, or None), and the positions of those that hold none
        of this format and setting (to be computed again from the run's figures: :meth:`set`). A submission
        given twice keeps its last."""
        out = cls(setting)
        blobs: dict[int, bytes] = {}  # by position: a submission's last
        undecoded: list[int] = []
        for k in {int(sid): k for k, sid in enumerate(submission_ids)}.values():
            blob = data[k]
            if blob is None or len(blob) < _HEADER.size:
                undecoded.append(k)
            else:
                blobs[k] = blob
        by_header: dict[tuple[int, bytes], list[int]] = {}
        for k, blob in blobs.items():
            by_header.setdefault((len(blob), bytes(blob[: _HEADER.size])), []).append(k)
        m = len(metric_keys(setting))
        for (size, header), at in by_header.items():
            magic, fmt, groups, metrics, _ = _HEADER.unpack(header)
            layout = _layout(groups, metrics)
            if magic != _MAGIC or fmt != FORMAT or metrics != m:
                undecoded += at
            elif size != layout.itemsize:  # not as this version writes it: one at a time, as it always was
                for k in at:
                    out.set(int(submission_ids[k]), EntryPart.decode(blobs[k], setting))
            else:
                records = np.frombuffer(b"".join(blobs[k] for k in at), layout)
                sids = np.array([submission_ids[k] for k in at], dtype=np.int64).reshape(len(at))
                out._add_records(sids, records)
        undecoded.sort()
        return out, undecoded

    def _add_records(self, sids: np.ndarray, records: np.ndarray) -> None:
        ids = records["ids"]
        # each field contiguous: read in place, a field's values lie a record apart (1.5 kB), and every pass
        # over them then waits on memory
        fields = (
            np.ascontiguousarray(records[f]) for f in ("top", "bottom", "metric_ci", "stable_ci", "seed")
        )
        if (ids == ids[0]).all():
            self._add_rows(PartRows(sids, np.array(ids[0], dtype=np.int64), *fields))
            return
        lists, which = np.unique(ids, axis=0, return_inverse=True)
        every = PartRows(sids, np.zeros(0, np.int64), *fields)  # its group ids: each list's, below
        for j, group_ids in enumerate(lists):
            rows = every.taken(which.reshape(-1) == j)
            self._add_rows(dataclasses.replace(rows, ids=np.array(group_ids, dtype=np.int64)))

    def _add_rows(self, rows: PartRows) -> None:
        number = len(self.rows)
        self.rows.append(rows)
        for row, sid in enumerate(rows.submission_ids.tolist()):
            self._at[sid] = (number, row)

    def set(self, submission_id: int, part: EntryPart | None) -> None:
        """The entry's part (None: its run has no figures), in place of any it had here."""
        self._at.pop(submission_id, None)
        self.single[submission_id] = part

    def __getitem__(self, submission_id: int) -> EntryPart | None:
        at = self._at.get(submission_id)
        if at is None:
            return self.single[submission_id]
        return self.rows[at[0]].part(at[1], self.setting)

    def __contains__(self, submission_id: object) -> bool:
        return submission_id in self._at or submission_id in self.single

    def __iter__(self) -> Iterator[int]:
        yield from self._at
        yield from self.single

    def __len__(self) -> int:
        return len(self._at) + len(self.single)

    def ids_of(self, submission_id: int) -> bytes | None:
        """The entry's group ids as bytes (None: no part)."""
        at = self._at.get(submission_id)
        if at is not None:
            return self.rows[at[0]].ids.tobytes()
        part = self.single.get(submission_id)
        return None if part is None else part.ids.tobytes()

    def live_rows(self) -> list[PartRows]:
        """The rows whose entries were not set again since (:meth:`set`)."""
        out = []
        for number, rows in enumerate(self.rows):
            keep = np.array(
                [self._at.get(s, (-1, -1))[0] == number for s in rows.submission_ids.tolist()], dtype=bool
            ).reshape(len(rows.submission_ids))
            if keep.all():
                out.append(rows)
            elif keep.any():
                out.append(rows.taken(keep))
        return out


@dataclass(frozen=True, slots=True)
class Stacked:
    """Stacked entries' figures laid out for resampling (:meth:`samples`): made once, resampled a block of
    resamples at a time (a board's full computation)."""

    columns: np.ndarray  # (metrics × entries, groups) float64: the sum terms, metric-major
    weighed: np.ndarray  # (metrics, entries): a weight column that is not 1 in every group
    weights: np.ndarray  # (weighed, groups) float64: those weight columns
    weight_row: np.ndarray  # (metrics × entries,): where weighed, its row of ``weights``
    metrics: int
    entries: int

    @classmethod
    def of(cls, top: np.ndarray, bottom: np.ndarray) -> Stacked:
        """From ``top``/``bottom``: entries × groups × metrics (float32, :class:`EntryPart`'s)."""
        k, g, m = top.shape
        columns = np.ascontiguousarray(top.transpose(2, 0, 1), dtype=np.float64).reshape(m * k, g)
        weighed = ~np.all(bottom == 1.0, axis=1).T
        weights = np.ascontiguousarray(bottom.transpose(2, 0, 1)[weighed], dtype=np.float64)
        return cls(columns, weighed, weights, np.cumsum(weighed.reshape(-1)) - 1, m, k)

    def samples(self, plan: np.ndarray) -> np.ndarray:
        """The run figures under each resample of ``plan`` (resamples × groups): (metrics, entries,
        resamples), NaN = unmeasured; the ratio of resampled sums, as
        :func:`robobpp.scoring.stats.metric_samples` computes it.

        Metric-major, so that each metric's samples are one contiguous (entries, resamples) block for what
        follows (normalisation, timing noise). The sums are exact (:func:`robobpp.scoring.stats.as_resampled`),
        so an entry's samples are the same bits alone or stacked with others, in any block of resamples or
        of entries (:meth:`tile`)."""
        return self.tile(plan, 0, self.entries, np.empty((self.metrics, self.entries, plan.shape[0])))

    def tile(self, plan: np.ndarray, start: int, stop: int, out: np.ndarray) -> np.ndarray:
        """:meth:`samples` of entries ``start``..``stop`` alone, written into ``out`` (metrics, stop − start,
        resamples; each metric's rows contiguous) and returned: a full computation works through a board a
        cache-sized tile at a time. A matrix product per metric; a weight column that is 1 in every group (a
        metric measured in every group) sums to the group count in every resample: no product for it."""
        total = plan.sum(axis=1)  # the group count, exactly, in every resample
        with np.errstate(invalid="ignore", divide="ignore"):
            for j in range(self.metrics):  # in place, a metric at a time (no copy of the samples)
                base = j * self.entries
                means = np.matmul(self.columns[base + start : base + stop], plan.T, out=out[j])
                weighed = self.weighed[j, start:stop]
                if not weighed.any():
                    means /= total
                    continue
                # a pooled metric: every entry's weights, in place (their rows are in a run)
                if weighed.all():
                    first = int(self.weight_row[base + start])
                    sums = self.weights[first : first + stop - start] @ plan.T
                    np.divide(means, sums, out=means)
                    means[sums <= 0] = np.nan
                    continue
                rows = np.flatnonzero(weighed)
                sums = self.weights[self.weight_row[base + start + rows]] @ plan.T
                means[rows] = np.where(sums <= 0, np.nan, means[rows] / sums)
                plain = np.flatnonzero(~weighed)
                means[plain] /= total
        return out


def samples_of(top: np.ndarray, bottom: np.ndarray, plan: np.ndarray) -> np.ndarray:
    """Run figures of stacked entries (``top``/``bottom``: entries × groups × metrics, float32) under each
    resample: (metrics, entries, resamples) (:meth:`Stacked.samples`)."""
    return Stacked.of(top, bottom).samples(plan)


def entry_part(figures: Mapping[str, Any], setting: str) -> EntryPart:
    """A run's part from its per-group figures (``stats.group_figures``)."""
    keys = metric_keys(setting)
    ids = np.asarray(figures.get("ids") or [], dtype=np.int64)
    g = int(ids.shape[0])
    top = np.zeros((g, len(keys)))
    bottom = np.zeros((g, len(keys)))
    for j, key in enumerate(keys):
        if key in POOLED:
            pairs = np.asarray((figures.get("pooled") or {}).get(key) or [[0.0, 0.0]] * g, dtype=np.float64)
            top[:, j], bottom[:, j] = pairs.reshape(g, 2)[:, 0], pairs.reshape(g, 2)[:, 1]
        else:
            values = np.asarray(
                (figures.get("values") or {}).get(key) or [None] * g, dtype=np.float64
            ).reshape(g)
            ok = np.isfinite(values)
            top[:, j], bottom[:, j] = np.where(ok, values, 0.0), ok
    top, bottom = top.astype(np.float32), bottom.astype(np.float32)
    metric_ci = np.full((len(keys), 2), np.nan)
    stable_ci = (0.0, 0.0)
    seed = part_seed(top, bottom, setting)
    if g:
        s = samples_of(top[None], bottom[None], counts(g))
        lo, hi = stats.interval(s[:, 0, :].T)
        metric_ci[:, 0], metric_ci[:, 1] = lo, hi
        slo, shi = stats.interval(stable_samples(with_timing_noise(s, [seed], setting), setting).T)
        stable_ci = (float(slo[0]), float(shi[0]))
    return EntryPart(setting, ids, top, bottom, metric_ci, stable_ci, seed)


def part_seed(top: np.ndarray, bottom: np.ndarray, setting: str) -> int:
    """The seed of a run's timing noise from its (groups, metrics) figures: its per-group Decision Times, as
    :func:`robobpp.scoring.scores.score_board` seeds it from the recorded figures."""
    (key,) = RESOLVED
    j = metric_keys(setting).index(key)
    return stats.timing_seed(np.where(bottom[:, j] > 0, top[:, j], np.nan))


def with_timing_noise(
    samples: np.ndarray,
    seeds: Sequence[int | None] | np.ndarray,
    setting: str,
    rows: np.ndarray | None = None,
) -> np.ndarray:
    """Entries' (metrics, entries, resamples) samples, in place, with each one's Decision Time moved by its
    timing noise (:func:`robobpp.scoring.scores.add_timing_noise`; ``seeds`` a uint64 array: every entry
    seeded); ``rows``: which resamples of the plan."""
    rows = np.arange(samples.shape[2]) if rows is None else rows
    for key in RESOLVED:
        add_timing_noise(samples[metric_keys(setting).index(key)], seeds, rows)
    return samples


def stable_samples(samples: np.ndarray, setting: str) -> np.ndarray:
    """The stable score under each resample from (metrics, ...) samples: (...)."""
    total = np.zeros(samples.shape[1:])
    for j, (key, weight) in enumerate(WEIGHTS[setting].items()):
        score = anchored(samples[j], key)
        score *= weight
        total += score
    return total


def part_of_run(figures: Mapping[str, Any] | None, setting: str) -> bytes | None:
    """What a finished run stores in ``runs.entry``: its encoded part, or None without figures."""
    if not figures or not figures.get("ids") or setting not in WEIGHTS:
        return None
    return entry_part(figures, setting).encode()


class IdIndex:
    """Submission ids mapped to integers, as two arrays sorted by id: 16 bytes an id where a dict of Python
    ints took ≈ 100 (BENCHMARKS.md, "The board engine"), looked up many at a time by binary search. What a
    board keeps per entry is reached through it (:class:`PartTable`'s rows, a board's slots)."""

    def __init__(self) -> None:
        self.ids = np.zeros(0, np.int64)  # ascending
        self.values = np.zeros(0, np.int64)

    def __len__(self) -> int:
        return len(self.ids)

    def _positions(self, ids: Sequence[int] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each id's position in the sorted arrays, and whether it is there."""
        wanted = np.asarray(ids, dtype=np.int64).reshape(-1)
        at = np.searchsorted(self.ids, wanted)
        found = np.zeros(len(wanted), dtype=bool)
        if len(self.ids):
            inside = at < len(self.ids)
            found[inside] = self.ids[at[inside]] == wanted[inside]
        return at, found

    def __contains__(self, id_: object) -> bool:
        return isinstance(id_, int | np.integer) and bool(self._positions([int(id_)])[1][0])

    def contains(self, ids: Sequence[int] | np.ndarray) -> np.ndarray:
        return self._positions(ids)[1]

    def get(self, ids: Sequence[int] | np.ndarray) -> np.ndarray:
        """Each id's value, -1 where it has none."""
        at, found = self._positions(ids)
        out = np.full(len(found), -1, dtype=np.int64)
        out[found] = self.values[at[found]]
        return out

    def add(self, ids: Sequence[int] | np.ndarray, values: Sequence[int] | np.ndarray) -> None:
        """Map ids that are not there (each once) to values."""
        new = np.asarray(ids, dtype=np.int64).reshape(-1)
        order = np.argsort(new, kind="stable")
        at = np.searchsorted(self.ids, new[order])
        self.ids = np.insert(self.ids, at, new[order])
        self.values = np.insert(self.values, at, np.asarray(values, dtype=np.int64).reshape(-1)[order])

    def remove(self, ids: Sequence[int] | np.ndarray) -> np.ndarray:
        """Forget the ids (those not there are skipped); their values."""
        at, found = self._positions(ids)
        at = np.unique(at[found])
        gone: np.ndarray = self.values[at]
        self.ids, self.values = np.delete(self.ids, at), np.delete(self.values, at)
        return gone


class PartTable:
    """Many entries' parts as matrices, one block per distinct group-id list: what a board keeps of each
    entry between updates, so that any entry's samples can be computed again without SQL.

    A block holds one float32 matrix (entries × groups × metrics): the sum term where the group was measured
    and NaN where it was not (a metric that is not pooled has weight 1 or 0, and sum term 0 where it is 0,
    so the NaN says both); a pooled metric's weights (its denominators) in a second matrix. The sum terms
    and weights :meth:`stacked` gives back are the parts' own, bit for bit. Beside them, per entry: the
    metric and stable intervals and the timing seed (what :meth:`EntryPart.decode` reads). About 0.7 kB an
    entry of a 30-group Physics board, where an :class:`EntryPart` kept its stored bytes and five arrays
    (≈ 3.5 kB with their Python objects)."""

    def __init__(self, setting: str) -> None:
        self.setting = setting
        self.keys = metric_keys(setting)
        #: the columns whose weights are kept (the pooled ones; every column once a part breaks the rule)
        self._pooled = np.array([k in POOLED for k in self.keys], dtype=bool)
        self._blocks: list[_Block | None] = []  # by number; None: emptied
        self._numbers: dict[bytes, int] = {}  # group ids -> block number
        #: where each entry's part is: its block's number and row, as ``number << 32 | row``
        self._where = IdIndex()

    def _located(self, submission_ids: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """The entries' block numbers and rows (KeyError: an entry without a part)."""
        where = self._where.get(submission_ids)
        if (where < 0).any():
            raise KeyError(int(np.asarray(submission_ids, dtype=np.int64)[where < 0][0]))
        return where >> 32, where & 0xFFFFFFFF

    def __contains__(self, submission_id: object) -> bool:
        return submission_id in self._where

    def contains(self, submission_ids: Sequence[int] | np.ndarray) -> np.ndarray:
        """Per id, whether the table holds its part (:meth:`__contains__` of many)."""
        return self._where.contains(submission_ids)

    def __len__(self) -> int:
        return len(self._where)

    def put(self, submission_id: int, part: EntryPart) -> None:
        """Keep ``part`` as the entry's (replacing the one it had)."""
        self.put_many({submission_id: part})

    def put_many(self, parts: Mapping[int, EntryPart | None]) -> None:
        """Keep many parts (replacing those the entries had; None: the entry has none any more): one
        allocation per block, not one per entry; the rows of :class:`StoredParts` as they are."""
        if not parts:
            return
        self.drop_many(list(parts))
        single = parts.single if isinstance(parts, StoredParts) else parts
        batches = parts.live_rows() if isinstance(parts, StoredParts) else []
        by_ids: dict[bytes, list[tuple[int, EntryPart]]] = {}
        for sid, part in single.items():
            if part is not None:
                by_ids.setdefault(part.ids.tobytes(), []).append((int(sid), part))
        sids: list[np.ndarray] = []
        blocks: list[np.ndarray] = []
        rows: list[np.ndarray] = []
        for items in by_ids.values():
            batches.append(_stacked_rows([sid for sid, _ in items], [p for _, p in items]))
        for batch in batches:
            ids = batch.ids.astype(np.int64).tobytes()
            number = self._numbers.get(ids)
            if number is None:
                number = self._numbers[ids] = len(self._blocks)
                self._blocks.append(_Block(len(batch.ids), len(self.keys), self._pooled))
            block = self._blocks[number]
            assert block is not None
            rows.append(block.add_rows(batch))
            sids.append(batch.submission_ids)
            blocks.append(np.full(len(batch.submission_ids), number, dtype=np.int64))
        if sids:
            where = (np.concatenate(blocks) << 32) | np.concatenate(rows).astype(np.int64)
            self._where.add(np.concatenate(sids), where)

    def drop(self, submission_id: int) -> None:
        self.drop_many([submission_id])

    def drop_many(self, submission_ids: Sequence[int]) -> None:
        """Forget the entries' parts (an id without one is skipped)."""
        gone = self._where.remove(submission_ids)
        for number, row in zip((gone >> 32).tolist(), (gone & 0xFFFFFFFF).tolist(), strict=True):
            block = self._blocks[number]
            assert block is not None
            block.remove(row)
            if block.size == 0:
                self._blocks[number] = None
                del self._numbers[next(k for k, v in self._numbers.items() if v == number)]

    def _by_block(self, submission_ids: Sequence[int]) -> list[tuple[_Block, np.ndarray, np.ndarray]]:
        """The entries grouped by block: each block, the entries' positions in ``submission_ids``, their rows."""
        numbers, rows = self._located(submission_ids)
        out = []
        for number in np.unique(numbers).tolist():
            block = self._blocks[number]
            assert block is not None
            at = np.flatnonzero(numbers == number)
            out.append((block, at, rows[at]))
        return out

    def stacked(self, submission_ids: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """The entries' sum terms and weights, each (entries, groups, metrics): their parts' ``top`` and
        ``bottom`` stacked (every entry of the same group ids)."""
        found = self._by_block(submission_ids)
        if len(found) != 1:
            raise ValueError("stacked parts must share their group ids")
        block, _, rows = found[0]
        return block.top_bottom(rows.astype(np.intp))

    def seeds(self, submission_ids: Sequence[int]) -> np.ndarray:
        """The entries' timing seeds (each one's part's), uint64: what the timing noise takes."""
        out = np.zeros(len(submission_ids), dtype=np.uint64)
        for block, at, rows in self._by_block(submission_ids):
            out[at] = block.seeds[rows]
        return out

    def intervals_of(self, submission_ids: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """The entries' metric intervals (entries × metrics × 2, NaN = none) and stable intervals (entries × 2),
        gathered a block at a time."""
        metric = np.empty((len(submission_ids), len(self.keys), 2))
        stable = np.empty((len(submission_ids), 2))
        for block, at, rows in self._by_block(submission_ids):
            metric[at], stable[at] = block.metric_ci[rows], block.stable_ci[rows]
        return metric, stable

    def shown_intervals(self, submission_ids: np.ndarray, own: np.ndarray) -> MetricIntervals:
        """The metric intervals of the entries whose ``own`` is set (the others: none), as a board's snapshot
        reads them later: the blocks' arrays themselves, frozen, and each entry's block and row in them. A
        block copies its array before it next writes it (copy on write), so what a snapshot reads never
        changes — 8 bytes an entry where a copy of its intervals took ≈ 100."""
        numbers = np.full(len(submission_ids), -1, dtype=np.int32)
        rows = np.zeros(len(submission_ids), dtype=np.int32)
        at = np.flatnonzero(own)
        if len(at):
            numbers[at], rows[at] = self._located(np.asarray(submission_ids)[at].tolist())
        arrays = []
        for block in self._blocks:
            if block is None:
                arrays.append(_NO_INTERVALS)
                continue
            block.metric_ci.flags.writeable = False
            arrays.append(block.metric_ci)
        return MetricIntervals(tuple(arrays), numbers, rows, len(self.keys))

    def nbytes(self) -> int:
        where = self._where.ids.nbytes + self._where.values.nbytes
        return where + sum(b.nbytes() for b in self._blocks if b is not None)


_NO_INTERVALS = np.zeros((0, 0, 2))


@dataclass(frozen=True, slots=True)
class MetricIntervals:
    """Entries' metric intervals as :meth:`PartTable.shown_intervals` hands them out: ``of(i)`` is entry
    ``i``'s (metrics × 2; NaN: none), read from the part table's frozen arrays."""

    arrays: tuple[np.ndarray, ...]
    numbers: np.ndarray  # per entry its block's number (-1: no intervals)
    rows: np.ndarray
    metrics: int

    def of(self, i: int) -> np.ndarray:
        number = int(self.numbers[i])
        if number < 0:
            return np.full((self.metrics, 2), np.nan)
        interval: np.ndarray = self.arrays[number][int(self.rows[i])]
        return interval


class _Block:
    """The parts of one group-id list (:class:`PartTable`), rows reused once freed."""

    def __init__(self, groups: int, metrics: int, pooled: np.ndarray) -> None:
        self.groups, self.metrics, self.pooled = groups, metrics, pooled.copy()
        self.figures = np.zeros((0, groups, metrics), np.float32)
        self.weights = np.zeros((0, groups, int(pooled.sum())), np.float32)
        self.metric_ci = np.zeros((0, metrics, 2))
        self.stable_ci = np.zeros((0, 2))
        self.seeds = np.zeros(0, dtype=np.uint64)
        self.size = 0
        self._free: list[int] = []
        self._used = 0  # rows ever handed out (the free ones among them in ``_free``)

    def nbytes(self) -> int:
        arrays = (self.figures, self.weights, self.metric_ci, self.stable_ci, self.seeds)
        return sum(a.nbytes for a in arrays)

    def reserve(self, more: int) -> None:
        """Room for ``more`` rows (grown by a tenth beyond them: an update adds a row or two at a time)."""
        needed = self._used + max(0, more - len(self._free))
        if needed <= self.figures.shape[0]:
            return
        capacity = needed if self.figures.shape[0] == 0 else max(needed, self.figures.shape[0] * 11 // 10 + 8)

        def grown(a: np.ndarray) -> np.ndarray:
            out = np.zeros((capacity, *a.shape[1:]), dtype=a.dtype)
            out[: a.shape[0]] = a
            return out

        self.figures, self.weights = grown(self.figures), grown(self.weights)
        self.metric_ci, self.stable_ci, self.seeds = (
            grown(self.metric_ci),
            grown(self.stable_ci),
            grown(self.seeds),
        )

    def add_rows(self, parts: PartRows) -> np.ndarray:
        """Keep the parts (of this block's group ids); returns their rows."""
        n = len(parts.submission_ids)
        top = parts.top.reshape(n, self.groups, self.metrics)
        bottom = parts.bottom.reshape(top.shape)
        plain = ~self.pooled
        # a column kept without weights must have weight 1 where measured, and sum term 0 where not
        if not (
            np.all((bottom[..., plain] == 1.0) | ((bottom[..., plain] == 0.0) & (top[..., plain] == 0.0)))
            and np.all(np.isfinite(top[..., plain][bottom[..., plain] == 1.0]))
        ):
            self._keep_every_weight()
            plain = ~self.pooled
        self.reserve(n)
        reused = self._free[-n:][::-1] if n else []
        del self._free[len(self._free) - len(reused) :]
        rows = np.array(reused + list(range(self._used, self._used + n - len(reused))), dtype=np.intp)
        # new rows only (a board's start): a slice, written in place, where a list of rows is gathered first
        at: slice | np.ndarray = slice(self._used, self._used + n) if not reused else rows
        self._used += n - len(reused)
        self.figures[at] = np.where(plain & (bottom == 0.0), np.nan, top)
        self.weights[at] = bottom[..., self.pooled]
        if not self.metric_ci.flags.writeable:  # a board's snapshot reads it (``shown_intervals``)
            self.metric_ci = self.metric_ci.copy()
        self.metric_ci[at] = parts.metric_ci.reshape(n, self.metrics, 2)
        self.stable_ci[at] = parts.stable_ci.reshape(n, 2)
        self.seeds[at] = parts.seeds
        self.size += n
        return rows

    def _keep_every_weight(self) -> None:
        """A part whose weights the NaN cannot say (never written by :func:`entry_part`): keep every
        column's weights from now on, as they were."""
        if self.pooled.all():
            return
        top, bottom = self.top_bottom(np.arange(self.figures.shape[0]))
        self.pooled = np.ones(self.metrics, dtype=bool)
        self.figures, self.weights = top, bottom

    def remove(self, row: int) -> None:
        self._free.append(row)
        self.size -= 1

    def top_bottom(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        top = self.figures[rows]
        bottom = np.empty_like(top)
        plain = ~self.pooled
        measured = ~np.isnan(top[:, :, plain])
        bottom[:, :, plain] = measured
        top[:, :, plain] = np.where(measured, top[:, :, plain], 0.0)
        bottom[:, :, self.pooled] = self.weights[rows]
        return top, bottom


def _stacked_rows(submission_ids: Sequence[int], parts: Sequence[EntryPart]) -> PartRows:
    """Parts of one group-id list given one by one, as rows."""
    n = len(parts)
    return PartRows(
        np.array(submission_ids, dtype=np.int64).reshape(n),
        parts[0].ids,
        np.stack([p.top for p in parts]),
        np.stack([p.bottom for p in parts]),
        np.stack([p.metric_ci for p in parts]),
        np.array([p.stable_ci for p in parts], dtype=np.float64).reshape(n, 2),
        np.array([p.seed for p in parts], dtype=np.uint64).reshape(n),
    )
