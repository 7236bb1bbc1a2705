"""A board kept between updates, as columns: only the global part of the scoring is redone when entries arrive.

Each entry's own part (its figures as a matrix, metric and stable intervals: :mod:`robobpp.scoring.entries`)
was computed when its run finished; the board keeps every entry's as matrices (:class:`PartTable`) and the
rest of what it knows of an entry in arrays, one element per entry: no Python object per entry but its
public fields, kept as one compact JSON string. What an arriving entry can change on a board is global:

* the min–max of each metric in each resample (the relative score's normalisation). The board keeps them
  (resamples × metrics). When a new entry lies inside them in every resample — the common case — no other
  entry's relative score samples move: only the new entry's samples, score interval and the point ranks
  are computed. When it moves some (a new best or worst), only those resamples of the others are computed
  again; when an entry leaves, or the board's groups change, every entry's samples are (from the figures
  kept: a block of resamples of every entry at a time, each sample computed once).
* ranks and rank intervals. Point ranks and the best entries' rank intervals (the default view, one
  entry per participant) are recomputed on every update. The all-entries rank intervals need every entry's
  rank in every resample (each resample ranked: 0.1 s a board at 10,000 entries, BENCHMARKS.md): they are
  computed by a full computation (``rank_intervals=True``, the board worker's refresh timer); between two,
  an entry keeps the interval last computed and a new entry has none (served as null).

Samples are never kept: an entry's are computed again from its figures when needed (the grid's means:
:meth:`BoardMatrix.grid_samples`). Each update hands out a :class:`~robobpp.boards.ranking.RankedView` whose
rows are built on demand from a snapshot of the columns, with a serial per row that changes whenever what
the row shows does (the publisher serialises a row again only then).

The board produced equals :func:`robobpp.boards.ranking.build_board` of the same rows (to the last bit of
each entry's own samples: its float32 figures make every resampled sum exact, so its samples are the same
computed alone, among others or in any block of resamples), except for those rank intervals.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta, timezone
from typing import Any

import numpy as np
import orjson

from robobpp.boards.ranking import (
    GRID_RESAMPLES,
    best_of_participants,
    board_tops,
    participant_key,
    ranked_of,
    status_reason,
)
from robobpp.boards.records import Board, ForGrid, LazyRows, Positions, RankedView, Row
from robobpp.scoring import stats
from robobpp.scoring.entries import (
    EntryPart,
    IdIndex,
    MetricIntervals,
    PartTable,
    Stacked,
    counts,
    metric_keys,
    stable_samples,
    with_timing_noise,
)
from robobpp.scoring.kernels import compiled
from robobpp.scoring.scores import (
    RESOLVED,
    WEIGHTS,
    add_weighted_min_max,
    competition_ranks,
    min_max,
    stable_scores_of,
)

#: Loads the stored parts of a board's entries by submission id (None: the run has no figures).
PartLoader = Callable[[Sequence[int]], Mapping[int, EntryPart | None]]
#: Entries whose samples are computed at a time (bounds the transient array: chunk × resamples × metrics).
CHUNK = 512
#: Samples computed at a time in a full computation (metrics × entries × a block of resamples: 64 MB; more
#: past 15,000 entries, a block being at least 64 resamples).
BLOCK_VALUES = 8_000_000
#: Samples of one metric a full computation works on at a time within a block (entries × the block's resamples:
#: 1.3 MB, about a core's level-2 cache): each pass over a tile finds it in the cache.
TILE_VALUES = 160_000
_NONE = np.zeros((0, 0))
#: The grid's resamples: the first of the plan's.
_GRID_ROWS = np.arange(GRID_RESAMPLES)


class Workspace:
    """The large arrays of a full computation, reused from block to block and board to board: every entry's
    relative scores in every resample (1,000 × entries, float64: 80 MB at 10,000 entries, 800 MB at 100,000),
    their ranks, a block of samples. Each new array that size is fresh pages the kernel must find and zero: at
    100,000 submissions a start spent more than a fifth of its CPU in the kernel (BENCHMARKS.md, "The board
    engine"). The engine holds one for a full computation and drops it after (``BoardEngine._full``); a board
    computed without one uses its own, for its blocks."""

    def __init__(self) -> None:
        self._arrays: dict[str, np.ndarray] = {}

    def array(self, name: str, shape: tuple[int, ...], dtype: Any = np.float64) -> np.ndarray:
        """An uninitialised array ``shape`` of ``dtype`` for ``name``: the memory the last one of that name had,
        when it fits (so the last one's values are overwritten)."""
        size = math.prod(shape)
        kept = self._arrays.get(name)
        if kept is None or kept.dtype != np.dtype(dtype) or kept.size < size:
            self._arrays.pop(name, None)  # let go before its successor is made (freed unless a view is held)
            kept = self._arrays[name] = np.empty(size, dtype)
        return kept[:size].reshape(shape)


class _Columns:
    """Arrays of one element (or row) per entry slot, grown together."""

    def __init__(self, metrics: int) -> None:
        self.size = 0
        self.sid = np.zeros(0, np.int64)
        self.episodes = np.zeros(0, np.int32)
        self.failures = np.zeros(0, np.int32)
        self.policy_failed = np.zeros(0, bool)
        self.submission_failed = np.zeros(0, bool)
        self.who = np.zeros(0, np.int32)  # participant key, coded
        self.ids = np.zeros(0, np.int32)  # group ids, coded; -1: no figures
        self.points = np.zeros((0, metrics))  # point metrics, NaN = missing
        self.stable = np.zeros(0)  # point stable score
        self.version = np.zeros(0, np.int64)  # changes whenever the entry's own figures do
        # scored under the board's current min–max
        self.scored = np.zeros(0, bool)
        self.own = np.zeros(0, bool)  # scored with its figures (else its point metrics in every resample)
        self.score_ci = np.zeros((0, 2))
        self.stable_ci = np.zeros((0, 2))
        self.order = np.zeros((0, 4))  # the order statistics its score interval interpolates between
        self.rank_ci = np.zeros((0, 2), np.int32)  # -1: not computed since it arrived
        self.scoring = np.zeros(0, np.int64)  # a hash of what of its row its scoring depends on
        # a hash of what its row showed when last handed out, and the row's serial
        self.shown = np.zeros(0, np.uint64)
        self.serial = np.zeros(0, np.int64)
        # its metrics' key order, coded (-1: its metrics are kept in its public fields, not as its points)
        self.named = np.zeros(0, np.int32)
        # its run's finish time (``_times``): wall time (NaT where none, or where it is kept beside as it
        # is) and time zone, coded
        self.completed = np.zeros(0, "datetime64[us]")
        self.zone = np.zeros(0, np.int32)

    def freeze(self) -> None:
        """Make the columns a snapshot reads (``SHOWN``) read-only: the snapshot holds them, not copies."""
        for name in SHOWN:
            getattr(self, name).flags.writeable = False

    def thaw(self) -> None:
        """Copy the frozen columns before they are written (the snapshot keeps the ones it holds)."""
        for name in SHOWN:
            column = getattr(self, name)
            if not column.flags.writeable:
                setattr(self, name, column.copy())

    def grow(self, needed: int) -> None:
        if needed <= len(self.sid):
            return
        capacity = max(needed, len(self.sid) * 11 // 10 + 16)
        for name, a in vars(self).items():
            if isinstance(a, np.ndarray):
                out = np.zeros((capacity, *a.shape[1:]), dtype=a.dtype)
                out[: len(a)] = a
                setattr(self, name, out)


@dataclass(frozen=True, slots=True)
class _Stack:
    """Entries' figures ready to be resampled (:meth:`BoardMatrix._resample`): the measured ones stacked,
    the others' point metrics (metrics, entries), the measured ones' timing seeds (uint64, in the order of
    ``measured``; the others have no noise)."""

    stacked: Stacked | None
    measured: np.ndarray
    unmeasured: np.ndarray
    points: np.ndarray
    drawn: np.ndarray

    @property
    def entries(self) -> int:
        return len(self.measured) + len(self.unmeasured)

    def seeds(self) -> list[int | None]:
        """Every entry's timing seed, None where it has none (what the noise takes when some are unmeasured)."""
        seeds: list[int | None] = [None] * self.entries
        for k, seed in zip(self.measured.tolist(), self.drawn.tolist(), strict=True):
            seeds[k] = seed
        return seeds


#: The columns a snapshot reads by slot (frozen while it may: ``_Columns.freeze``).
SHOWN = ("points", "named", "score_ci", "stable", "stable_ci", "rank_ci", "completed", "zone")


@dataclass(frozen=True, slots=True)
class _Snapshot:
    """The ranked entries' figures as an update left them: what the rows handed out with that update are built
    from, on demand — later updates change the columns, never this.

    By slot (``slots[i]``: column ``i``'s), it reads the board's own columns and lists, frozen when the
    snapshot is made and copied by the board before it next writes them (copy on write: one copy of them in
    memory between updates, where a snapshot of copies doubled them); by column, what the update computed for
    it alone (scores, normalised metrics, metric intervals, best flags)."""

    keys: tuple[str, ...]
    slots: np.ndarray
    shared: list[Any]
    public: list[Any]
    completed: np.ndarray  # datetime64[us], with ``zone`` (``_times``)
    zone: np.ndarray
    odd_completed: dict[int, Any]  # finish times the arrays do not hold
    points: np.ndarray  # (slots, metrics): the point metrics, whence a row's metrics not kept in ``public``
    named: np.ndarray  # its metrics' key order in ``coded`` (-1: its metrics are in ``public``)
    coded: list[Any]
    score_ci: np.ndarray
    stable: np.ndarray
    stable_ci: np.ndarray
    rank_ci: np.ndarray
    scores: np.ndarray  # by column from here on
    normalized: np.ndarray
    intervals: MetricIntervals
    best: np.ndarray

    def row(self, i: int) -> Row:
        """Column ``i``'s row of the all-entries view without its rank (nor its participant's entry count,
        which moves with every entry they add: the reader puts it in)."""
        s = int(self.slots[i])
        low, high = (int(x) for x in self.rank_ci[s])
        intervals = self.intervals.of(i).tolist()
        code = int(self.named[s])
        metrics = None if code < 0 else _metrics(self.coded[code], self.keys, self.points[s])
        completed = _time(self.completed[s], self.coded[self.zone[s]], self.odd_completed.get(s))
        return _public(self.shared[s], self.public[s], completed, metrics) | {
            "rank": None,
            "rank_low": None if low < 0 else low,
            "rank_high": None if high < 0 else high,
            "score": float(self.scores[i]),
            "score_low": float(self.score_ci[s, 0]),
            "score_high": float(self.score_ci[s, 1]),
            "stable": float(self.stable[s]),
            "stable_low": float(self.stable_ci[s, 0]),
            "stable_high": float(self.stable_ci[s, 1]),
            "normalized": dict(zip(self.keys, self.normalized[i].tolist(), strict=True)),
            "intervals": {
                k: [a, b] if math.isfinite(a) else None
                for k, (a, b) in zip(self.keys, intervals, strict=True)
            },
            "best": bool(self.best[i]),
        }


class SharedFields:
    """Each submission's fields that all of its rows show alike (``_PUBLIC``: its id, name, participant,
    whether it is a baseline, its verdict), packed once for all of a track's boards: the fifteen boards of a
    track kept fifteen copies (≈ 100 bytes an entry: BENCHMARKS.md, "The board engine"). A board keeps a
    reference; a submission whose fields change gets a new object (rows handed out keep the old one)."""

    def __init__(self) -> None:
        self._by_id: dict[int, Any] = {}

    def __len__(self) -> int:
        return len(self._by_id)

    def packed(self, submission_id: int, fields: dict[str, Any]) -> Any:
        """``fields`` packed (:func:`_packed`): the object kept for the submission when they are the same."""
        kept = self._by_id[submission_id] = _same_or(self._by_id.get(submission_id), _packed(fields))
        return kept

    def keep_only(self, submission_ids: Iterable[int]) -> None:
        """Forget the submissions not among ``submission_ids`` (those that left the track's boards)."""
        keep = set(submission_ids)
        for sid in [s for s in self._by_id if s not in keep]:
            del self._by_id[sid]


class BoardMatrix:
    """One board (dataset × setting × loop × lookahead of a track) kept between updates.

    ``rows`` are what :func:`robobpp.db.queries.board_runs` returns without ``entry``, with ``ids``: the
    run's group ids as bytes (None without figures). ``load`` reads stored parts by submission id (only for
    rows upserted without theirs).
    """

    def __init__(
        self,
        dataset: str,
        setting: str,
        track: str,
        loop: str,
        load: PartLoader,
        lookahead: int = 0,
        shared: SharedFields | None = None,
    ) -> None:
        if setting not in WEIGHTS:
            raise ValueError(f"unknown setting {setting!r}; expected one of {', '.join(WEIGHTS)}")
        self.dataset, self.setting, self.track, self.loop = dataset, setting, track, loop
        self.lookahead = lookahead
        self.load = load
        self.keys = metric_keys(setting)
        #: Per metric, the floor of its min–max (``scores.RESOLVED``): the bounds kept are floored, so an entry
        #: whose time moves only below the floor moves no bound (nobody is renormalised for it)
        self._floors = np.array([RESOLVED[k][0] if k in RESOLVED else -np.inf for k in self.keys])
        self._weights = np.array([WEIGHTS[setting][k] for k in self.keys])
        self._c = _Columns(len(self.keys))
        self._slot = IdIndex()  # submission id -> its slot in the columns
        self._free: list[int] = []
        #: Each entry's public fields (JSON, or the dict where JSON would not give it back) and finish time:
        #: its submission's (one object for all of the track's boards: ``shared``) and its run's.
        self.shared = SharedFields() if shared is None else shared
        self._shared: list[Any] = []
        self._public: list[Any] = []
        #: finish times the columns do not hold as they were, by slot (``_times``; a datetime, what the
        #: database gives, is in ``_Columns.completed`` and ``zone``)
        self._odd_completed: dict[int, Any] = {}
        #: whether the last snapshot holds the lists above (copied before they are next written)
        self._lists_shown = False
        self._parts = PartTable(setting)
        self._codes: dict[Any, int] = {}
        self._coded: list[Any] = []
        self._basis: tuple[Any, ...] | None = None
        self._lo = self._hi = np.zeros((0, 0))
        self._plan = np.ones((stats.RESAMPLES, 1))
        #: The ranked entries' slots as last handed out (column order) and which used their figures.
        self._ranked = np.zeros(0, np.intp)
        self._usable = np.zeros(0, bool)
        #: Per resample of the grid's, the update that last changed it for entries already on the board
        #: (a grid recomputes those of its means); ``stamp``: the board's update count.
        self.stamp = 0
        self.resample_stamps = np.zeros(GRID_RESAMPLES, np.int64)
        #: A full computation's grid samples of every column, until the engine takes them (take_grid_samples).
        self._grid_kept: tuple[np.ndarray, np.ndarray] | None = None
        #: Bumped whenever entries already on the board were renormalised (a resample's min–max moved).
        self.epoch = 0
        #: Counters of what updates did (BENCHMARKS.md): renormalised rows, entries recomputed in full.
        self.shifted_rows = 0
        self.recomputed = 0

    def __len__(self) -> int:
        return len(self._slot)

    def __contains__(self, submission_id: object) -> bool:
        return submission_id in self._slot

    def submission_ids(self) -> list[int]:
        return [int(s) for s in self._slot.ids.tolist()]

    def nbytes(self) -> int:
        """The bytes of the board's arrays and figures (its public fields aside)."""
        arrays = [a for a in vars(self._c).values() if isinstance(a, np.ndarray)]
        return sum(a.nbytes for a in arrays) + self._parts.nbytes()

    def _thaw(self) -> None:
        """Copy what the last snapshot holds before writing it (``_Snapshot``: copy on write)."""
        self._c.thaw()
        if self._lists_shown:
            self._shared, self._public = list(self._shared), list(self._public)
            self._odd_completed = dict(self._odd_completed)
            self._lists_shown = False

    def _code(self, value: Any) -> int:
        code = self._codes.get(value)
        if code is None:
            code = self._codes[value] = len(self._coded)
            self._coded.append(value)
        return code

    # -- entries arriving and leaving

    def apply(
        self,
        upsert: Iterable[Mapping[str, Any]] = (),
        remove: Iterable[int] = (),
        parts: Mapping[int, EntryPart | None] | None = None,
    ) -> None:
        """Add or replace rows (``parts``: their parts when already at hand), drop submissions."""
        self._thaw()
        remove = list(remove)
        for slot in self._slot.remove(remove).tolist():
            self._basis = None  # it may have held a min or max: renormalise everyone
            self._free.append(slot)
            self._shared[slot] = self._public[slot] = None
            self._odd_completed.pop(slot, None)
        self._parts.drop_many(remove)
        upsert = list(upsert)
        given: Mapping[int, EntryPart | None] = {} if parts is None else parts
        lacking = [int(r["submission_id"]) for r in upsert if int(r["submission_id"]) not in given]
        # a part of None: the run has no figures any more (``put_many`` forgets it, replaces the others)
        self._parts.put_many(given)
        if lacking:  # its part may have changed: read it again
            self._parts.put_many(self.load(lacking))
        c = self._c
        slots: list[int] = []
        sids = [int(row["submission_id"]) for row in upsert]
        new: dict[int, int] = {}  # the slots given in this call (a row may come twice)
        known = self._slot.get(sids).tolist()
        # room for every new row at once: grown a row at a time, a start of 10,000 copied every column ≈ 100 times
        c.grow(len(self._public) + max(0, known.count(-1) - len(self._free)))
        for row, sid, slot in zip(upsert, sids, known, strict=True):
            scoring = _scoring_fields(row)
            if slot < 0:
                slot = new.get(sid, -1)
            if slot < 0:
                if self._free:
                    slot = self._free.pop()
                else:
                    slot = len(self._public)
                    c.grow(slot + 1)
                    self._shared.append(None)
                    self._public.append(None)
                new[sid] = slot
                c.scored[slot] = False
                c.rank_ci[slot] = -1
            elif c.scoring[slot] != scoring:
                self._basis = None
                c.scored[slot] = False
                c.rank_ci[slot] = -1
            c.scoring[slot] = scoring
            slots.append(slot)
        if new:
            self._slot.add(list(new), list(new.values()))
        if slots:
            self._set(np.array(slots, dtype=np.intp), upsert)

    def _set(self, slots: np.ndarray, rows: Sequence[Mapping[str, Any]]) -> None:
        """Keep the rows' figures in their slots: a column at a time (a board's start sets 10,000)."""
        c = self._c
        extras = [row.get("extras") or {} for row in rows]
        metrics = [row.get("metrics") or {} for row in rows]
        episodes = [
            int(e.get("episodes") or row.get("episodes_total") or 0)
            for e, row in zip(extras, rows, strict=True)
        ]
        terminations = [e.get("terminations") for e in extras]
        c.sid[slots] = [int(row["submission_id"]) for row in rows]
        c.episodes[slots] = episodes
        failures = np.array([stats.policy_failure_count(t) for t in terminations], dtype=np.int64)
        c.failures[slots] = failures
        c.policy_failed[slots] = stats.runs_failed(failures, np.array(episodes, dtype=np.int64))
        c.submission_failed[slots] = [row.get("submission_status") == "failed" for row in rows]
        c.who[slots] = [self._code(participant_key(row)) for row in rows]
        c.ids[slots] = [-1 if row.get("ids") is None else self._code(row["ids"]) for row in rows]
        points, plain = _points_of(metrics, self.keys)
        c.points[slots] = points
        c.version[slots] = new_serials(len(rows))
        c.shown[slots] = 0  # its row is new (no row hashes to 0 but by a 2**-64 chance)
        named = []
        for slot, row, m, e, kept in zip(slots.tolist(), rows, metrics, extras, plain.tolist(), strict=True):
            self._shared[slot] = self.shared.packed(
                int(row["submission_id"]), {k: row.get(k) for k in _PUBLIC}
            )
            # metrics that are exactly the board's point metrics are not kept twice (≈ 250 bytes an entry)
            named.append(self._code(tuple(m)) if kept else -1)
            # the object the slot had when it packs the same (a refresh re-sets every row): ≈ 30 MB of small
            # objects made again among each board's transient rows left the heap holed after a refresh
            self._public[slot] = _same_or(
                self._public[slot], _packed({"extras": e} if kept else {"metrics": m, "extras": e})
            )
        c.named[slots] = named
        at, zones, odd = _times([row.get("completed_at") for row in rows], self._code)
        c.completed[slots], c.zone[slots] = at, zones
        if self._odd_completed:
            for slot in slots.tolist():
                self._odd_completed.pop(slot, None)
        for k, value in odd.items():
            self._odd_completed[int(slots[k])] = value
        # each entry's stable score from its own metrics: element-wise, so all at once
        c.stable[slots] = stable_scores_of(points, self.setting)

    def _metrics_of(self, slot: int) -> dict[str, float] | None:
        """An entry's metrics when they are kept as its points (None: they are in its public fields)."""
        code = int(self._c.named[slot])
        return None if code < 0 else _metrics(self._coded[code], self.keys, self._c.points[slot])

    # -- the board

    def board(
        self, *, rank_intervals: bool = False, for_grid: bool = False, workspace: Workspace | None = None
    ) -> Board:
        """The board now (``rank_intervals``: compute every entry's, a full computation; ``for_grid``: a full
        computation keeps its entries' grid samples for :meth:`take_grid_samples`; ``workspace``: the large
        arrays of a full computation, shared with the other boards computed in full after this one)."""
        self._thaw()
        c = self._c
        self.stamp += 1
        everyone = self._slot.values.astype(np.intp)  # by ascending id
        groups, ranked_mask = ranked_of(
            c.episodes[everyone], c.policy_failed[everyone], c.submission_failed[everyone]
        )
        ranked = everyone[ranked_mask]
        with_ids = ranked[c.ids[ranked] >= 0]
        code = int(c.ids[with_ids[0]]) if len(with_ids) else -1
        ids = self._coded[code] if code >= 0 else None
        plan = counts(len(ids) // 8) if ids else np.ones((stats.RESAMPLES, 1))
        usable = c.ids[ranked] == code if code >= 0 else np.zeros(len(ranked), bool)
        basis = (groups, ids, plan.shape)
        fresh = np.flatnonzero(~c.scored[ranked])
        full = (
            rank_intervals
            or self._basis != basis
            or len(ranked) - len(fresh) != int(c.scored[everyone].sum())
        )
        self._plan = plan
        rel_all = None
        if not full and len(fresh):
            new = self._samples(ranked[fresh], usable[fresh], plan)
            lo, hi = self._floored(_fmin(self._lo, new)), self._floored(_fmax(self._hi, new))
            moved = np.flatnonzero(~_same_rows(lo, self._lo) | ~_same_rows(hi, self._hi))
            if moved.size:
                old = np.flatnonzero(c.scored[ranked])
                self._shift(moved, lo, hi, ranked[old], usable[old], plan)
            self._score(new, ranked[fresh], usable[fresh])
        elif full:
            c.scored[everyone[~ranked_mask]] = False
            c.rank_ci[everyone[~ranked_mask]] = -1
            workspace = workspace or Workspace()  # a board computed alone makes its own
            rel_all = self._renormalise(ranked, usable, plan, workspace, for_grid=for_grid)
            self._basis = basis
            self.epoch += 1
            self.resample_stamps[:] = self.stamp
            if rank_intervals and len(ranked):
                ranks = stats.rank_samples(rel_all, out=workspace.array("ranks", rel_all.shape, np.int32))
                low, high = stats.rank_interval(ranks, overwrite_input=True)
                c.rank_ci[ranked, 0], c.rank_ci[ranked, 1] = low, high
        self._ranked, self._usable = ranked, usable

        def best_samples(chosen: list[int]) -> np.ndarray:
            if rel_all is not None:
                return rel_all[:, chosen].astype(np.float32)
            samples = self._samples(ranked[chosen], usable[chosen], plan)
            return self._relative(samples, self._lo, self._hi).T.astype(np.float32)

        return self._assemble(everyone, ranked, ranked_mask, groups, best_samples)

    # -- the parts of the computation

    def _samples(
        self, slots: np.ndarray, usable: np.ndarray, plan: np.ndarray, rows: np.ndarray | None = None
    ) -> np.ndarray:
        """Entries' metric samples: (metrics, entries, resamples), with their timing noise; an entry without
        usable figures keeps its point metrics in every resample (as ``score_board`` does). ``plan`` is the
        rows ``rows`` of the board's plan (default: all of it)."""
        return self._resample(self._stack(slots, usable), plan, rows)

    def _stack(self, slots: np.ndarray, usable: np.ndarray) -> _Stack:
        """What the entries' samples are made of, for :meth:`_resample`."""
        sids = self._c.sid[slots].tolist()
        measured = np.flatnonzero(usable)
        chosen = [sids[k] for k in measured.tolist()]
        if not self._parts.contains(chosen).all():
            raise ValueError(f"{self.dataset}/{self.setting}: an entry with group ids has no stored part")
        stacked = Stacked.of(*self._parts.stacked(chosen)) if chosen else None
        unmeasured = np.flatnonzero(~usable)
        points = self._c.points[slots[unmeasured]].T
        return _Stack(stacked, measured, unmeasured, points, self._parts.seeds(chosen))

    def _resample(self, stack: _Stack, plan: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """:meth:`_samples` of stacked entries under the plan's rows ``rows``."""
        if stack.stacked is not None and not len(stack.unmeasured):
            return with_timing_noise(stack.stacked.samples(plan), stack.drawn, self.setting, rows)
        out = np.empty((len(self.keys), stack.entries, plan.shape[0]))
        if stack.stacked is not None:
            out[:, stack.measured] = stack.stacked.samples(plan)
        out[:, stack.unmeasured] = stack.points[:, :, None]
        return with_timing_noise(out, stack.seeds(), self.setting, rows)

    def _floored(self, bounds: np.ndarray) -> np.ndarray:
        """Per resample and metric, a min or max as the normalisation uses it (``scores.min_max``: NaN stays)."""
        return np.maximum(bounds, self._floors) if bounds.size else bounds

    def _relative(self, samples: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Relative score samples (entries, resamples) of (metrics, entries, resamples) samples under a
        min–max (resamples, metrics) (``scores._min_max_rows``)."""
        total = np.zeros(samples.shape[1:])
        last = len(self._weights) - 1
        for j, weight in enumerate(self._weights):
            add_weighted_min_max(
                total, samples[j], lo[:, j], hi[:, j], self.keys[j], weight, finish=j == last
            )
        return total

    def _score(self, samples: np.ndarray, slots: np.ndarray, usable: np.ndarray) -> np.ndarray:
        """Score the entries under the current min–max; returns their relative samples (entries, resamples)."""
        rel = self._relative(samples, self._lo, self._hi)
        self._scored(rel, slots, usable, samples)
        return rel

    def _scored(
        self, rel: np.ndarray, slots: np.ndarray, usable: np.ndarray, samples: np.ndarray | None = None
    ) -> None:
        """Keep the entries' score intervals from their relative samples (entries, resamples).

        An entry's metric and stable intervals are its stored part's (computed when its run finished);
        one without usable figures has point metrics in every resample, so no metric interval, and its
        stable interval from its ``samples`` (computed again when not given)."""
        c = self._c
        order, (lo, hi) = _order_and_interval(rel)
        c.order[slots] = order
        c.score_ci[slots, 0], c.score_ci[slots, 1] = lo, hi
        own = usable & self._parts.contains(c.sid[slots])
        c.own[slots] = own
        if not own.all():
            apart = (
                samples[:, ~own]
                if samples is not None
                else self._samples(slots[~own], usable[~own], self._plan)
            )
            slo, shi = stats.interval(stable_samples(apart, self.setting).T)
            c.stable_ci[slots[~own], 0], c.stable_ci[slots[~own], 1] = slo, shi
        if own.any():
            c.stable_ci[slots[own]] = self._parts.intervals_of(c.sid[slots[own]].tolist())[1]
        c.scored[slots] = True
        self.recomputed += len(slots)

    def _shift(
        self,
        moved: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        slots: np.ndarray,
        usable: np.ndarray,
        plan: np.ndarray,
    ) -> None:
        """A new entry moved the min or max of the resamples ``moved``: only those resamples of every other
        entry change. An entry whose changed samples stay on the same side of each order statistic its score
        interval uses keeps that interval (those statistics cannot move); the others are recomputed."""
        redo = []
        for a in range(0, len(slots), CHUNK):
            chunk = slots[a : a + CHUNK]
            samples = self._samples(chunk, usable[a : a + CHUNK], plan[moved], moved)
            before = self._relative(samples, self._lo[moved], self._hi[moved])
            after = self._relative(samples, lo[moved], hi[moved])
            order = self._c.order[chunk]
            side_before, side_after = _side(before, order), _side(after, order)
            kept = np.all((side_before == side_after) & (side_before >= 0), axis=1)
            redo.append(np.flatnonzero(~kept) + a)
        self._lo, self._hi = lo, hi
        self.resample_stamps[moved[moved < GRID_RESAMPLES]] = self.stamp
        again = np.concatenate(redo) if redo else np.zeros(0, np.intp)
        for a in range(0, len(again), CHUNK):
            at = again[a : a + CHUNK]
            self._score(self._samples(slots[at], usable[at], plan), slots[at], usable[at])
        self.shifted_rows += int(moved.size)
        self.epoch += 1

    def _renormalise(
        self,
        ranked: np.ndarray,
        usable: np.ndarray,
        plan: np.ndarray,
        workspace: Workspace,
        *,
        for_grid: bool = False,
    ) -> np.ndarray:
        """Every entry's samples again, a block of resamples at a time: a block's samples of every entry give
        its min–max, then every entry's relative scores in it. Keeps the min–max and each entry's score
        interval; returns every entry's relative samples (resamples, entries), made in ``workspace``.
        ``for_grid``: keeps, too, what :meth:`grid_samples` would compute again for every entry
        (:meth:`take_grid_samples`).

        Within a block, each pass works through the entries a cache-sized tile at a time (:data:`TILE_VALUES`):
        a tile's samples are made, moved by their timing noise and folded into the block's min–max while they
        are in the cache, then normalised a tile at a time; streaming the whole 64 MB block through memory for
        each of these steps made the computation wait on memory, not arithmetic. Every step is element-wise
        or exact (minima, maxima, exact sums), so the tiles give the same bits as the whole block."""
        m, n, r = len(self.keys), len(ranked), plan.shape[0]
        rel_all = workspace.array("relative", (r, n))
        lo, hi = np.full((r, m), np.nan), np.full((r, m), np.nan)
        width = min(r, GRID_RESAMPLES)
        grid = (np.empty((n, width), np.float32), np.empty((n, width), np.float32)) if for_grid else None
        if n:
            stack = self._stack(ranked, usable)
            # at least 64 resamples a block: each block's matrix products read every entry's figures once
            step = max(64, BLOCK_VALUES // (m * n))
            for a in range(0, r, step):
                rows = np.arange(a, min(r, a + step))
                tile = max(16, TILE_VALUES // len(rows))
                # one block's samples, written over by the next block's
                samples, low, high = self._block(stack, plan[rows], rows, workspace, tile)
                block = slice(a, a + len(rows))
                lo[block], hi[block] = self._floored(low), self._floored(high)
                for e in range(0, n, tile):
                    rel = self._relative(samples[:, e : e + tile], lo[block], hi[block])
                    rel_all[block, e : e + tile] = rel.T
                    if grid is not None and a < width:  # what grid_samples makes of these samples
                        w = min(len(rows), width - a)
                        grid[0][e : e + tile, a : a + w] = rel[:, :w]
                        grid[1][e : e + tile, a : a + w] = stable_samples(
                            samples[:, e : e + tile, :w], self.setting
                        )
                del samples
        self._lo, self._hi = lo, hi
        self._grid_kept = grid
        for a in range(0, n, CHUNK):
            at = slice(a, a + CHUNK)
            self._scored(np.ascontiguousarray(rel_all[:, at].T), ranked[at], usable[at])
        return rel_all

    def _block(
        self, stack: _Stack, plan: np.ndarray, rows: np.ndarray, workspace: Workspace, tile: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_resample` of every stacked entry under the plan's rows ``rows`` and their minima and maxima
        (resamples, metrics), made a tile of ``tile`` entries at a time when every entry is measured."""
        stacked = stack.stacked
        if stacked is None or len(stack.unmeasured):
            samples = self._resample(stack, plan, rows)
            return samples, _fmin(_NONE, samples), _fmax(_NONE, samples)
        out = workspace.array("samples", (stacked.metrics, stacked.entries, len(rows)))
        low, high = np.full((2, stacked.metrics, len(rows)), np.nan)  # none yet
        for e in range(0, stacked.entries, tile):
            stop = min(stacked.entries, e + tile)
            part = with_timing_noise(
                stacked.tile(plan, e, stop, out[:, e:stop]), stack.drawn[e:stop], self.setting, rows
            )
            _fold(low, high, part)
        return out, low.T, high.T

    def _points(self, ranked: np.ndarray) -> tuple[np.ndarray, list[int], np.ndarray, np.ndarray]:
        """Point scores, competition ranks and normalised metrics (``scores.score_entries``, vectorised:
        the same operations in the same order, so the same numbers)."""
        points = self._c.points[ranked]
        total = np.zeros(len(ranked))
        norm = np.zeros_like(points)
        for j, weight in enumerate(self._weights):
            col = points[:, j]
            present = np.isfinite(col)
            if present.any():
                norm[:, j] = min_max(col, col[present].min(), col[present].max(), self.keys[j])
            total += weight * norm[:, j]
        scores = np.array([round(x, 12) for x in total.tolist()])  # as score_entries: ties must tie
        return scores, competition_ranks(scores.tolist()), norm, points

    def _assemble(
        self,
        everyone: np.ndarray,
        ranked: np.ndarray,
        ranked_mask: np.ndarray,
        groups: int,
        best_samples: Callable[[list[int]], np.ndarray],
    ) -> Board:
        """The board, as :func:`~robobpp.boards.ranking.assemble_board` makes it (its rows built on demand)."""
        c = self._c
        submitted = Counter(c.who[everyone].tolist())
        unranked = []
        for slot in everyone[~ranked_mask].tolist():
            status, reason = status_reason(
                int(c.episodes[slot]),
                int(c.failures[slot]),
                bool(c.policy_failed[slot]),
                bool(c.submission_failed[slot]),
                groups,
            )
            unranked.append(
                _public(
                    self._shared[slot],
                    self._public[slot],
                    _time(c.completed[slot], self._coded[c.zone[slot]], self._odd_completed.get(slot)),
                    self._metrics_of(slot),
                )
                | {"status": status, "reason": reason, "entries_submitted": submitted[int(c.who[slot])]}
            )
        unranked.sort(key=lambda e: (e["status"], e["submission_id"]))
        scores, ranks, normalized, points = self._points(ranked)
        n = len(ranked)
        sids = c.sid[ranked]
        rank_of = np.asarray(ranks, dtype=np.int64).reshape(n)
        who = [self._coded[w] for w in c.who[ranked].tolist()]
        best_of = best_of_participants(who, sids, rank_of, scores.tolist(), best_samples)
        chosen = sorted(best_of)
        best = np.zeros(n, bool)
        best[chosen] = True
        # a row's serial changes whenever what it shows does (its rank aside)
        shown = np.column_stack(
            [
                scores,
                c.score_ci[ranked],
                c.stable_ci[ranked],
                c.rank_ci[ranked],
                best,
                c.own[ranked],
                normalized,
            ]
        )
        digest = _row_hashes(shown)
        differs = c.shown[ranked] != digest
        moved = ranked[differs]
        c.shown[moved] = digest[differs]
        c.serial[moved] = new_serials(len(moved))
        intervals = self._parts.shown_intervals(sids, c.own[ranked])
        c.freeze()
        self._lists_shown = True
        snap = _Snapshot(
            self.keys,
            ranked.copy(),
            self._shared,
            self._public,
            c.completed,
            c.zone,
            self._odd_completed,
            c.points,
            c.named,
            self._coded,  # only ever appended to
            c.score_ci,
            c.stable,
            c.stable_ci,
            c.rank_ci,
            scores,
            normalized,
            intervals,
            best,
        )
        order = np.lexsort((sids, rank_of))  # rank order, ties by id
        view = RankedView(sids[order], rank_of[order], sids, rank_of, c.serial[ranked], snap.row)
        counts_of = [submitted[w] for w in c.who[ranked].tolist()]

        def listed(i: int) -> Row:
            """Column ``i`` as the all-entries view lists it (``boards.finish_board``'s entry)."""
            d = snap.row(i) | {"rank": int(rank_of[i]), "entries_submitted": counts_of[i], "_column": i}
            b = best_of.get(i)
            if b is not None:
                d["best_rank"], d["best_rank_low"], d["best_rank_high"] = b
            return d

        # arrays, not lists, in what the rows are built from (10,000 int objects a board otherwise)
        entries = LazyRows(lambda: [listed(i) | {"_base": snap.row(i)} for i in order.tolist()])
        best_rows = [
            listed(i) | {"rank": b[0], "rank_low": b[1], "rank_high": b[2]} for i, b in best_of.items()
        ]
        best_rows.sort(key=lambda e: (e["rank"], e["submission_id"]))
        by_column = np.array([scores, c.stable[ranked]], dtype=np.float64).reshape(2, n)
        return Board(
            self.dataset,
            self.setting,
            self.track,
            groups,
            entries,
            unranked,
            best_rows,
            Positions(sids, order),
            {
                "best": board_tops(scores[chosen], points[chosen], self.keys),
                "all": board_tops(scores, points, self.keys),
            },
            self.loop,
            self.lookahead,
            ranked=view,
            for_grid=ForGrid(by_column),
        )

    # -- what the grid needs

    def versions(self) -> np.ndarray:
        """Per column of the last board handed out: a number that changes whenever the entry's own samples
        may have (its figures, or whether they are used)."""
        c = self._c
        return c.version[self._ranked] * 2 + self._usable

    def participants(self, columns: np.ndarray) -> list[str]:
        """Whose entries the last board's columns ``columns`` are (``boards.participant_key``)."""
        return [self._coded[w] for w in self._c.who[self._ranked[columns]].tolist()]

    def take_grid_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What :meth:`grid_samples` gives of every column, as the last full computation made them on its way
        (``board(..., for_grid=True)``), with the columns' submission ids (ascending), handed over once: the
        grid of a full computation sums them where it computed them all again (a quarter of each board's
        computation)."""
        kept, self._grid_kept = self._grid_kept, None
        if kept is None:
            raise ValueError(
                f"{self.dataset}/{self.setting}: no grid samples kept (board(for_grid=True) first)"
            )
        return self._c.sid[self._ranked], kept[0], kept[1]

    def grid_samples(
        self, columns: np.ndarray, resamples: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The relative and stable score samples (float32, entries × resamples) of the last board's columns
        ``columns`` under the grid's resamples (``resamples``: those of them), as ``score_board`` gives them."""
        rows = _GRID_ROWS if resamples is None else resamples
        plan = self._plan[rows]
        rel = np.empty((len(columns), len(rows)), np.float32)
        stable = np.empty((len(columns), len(rows)), np.float32)
        for a in range(0, len(columns), CHUNK):
            at = columns[a : a + CHUNK]
            samples = self._samples(self._ranked[at], self._usable[at], plan, rows)
            rel[a : a + CHUNK] = self._relative(samples, self._lo[rows], self._hi[rows])
            stable[a : a + CHUNK] = stable_samples(samples, self.setting)
        return rel, stable


def _metrics(order: tuple[str, ...], keys: tuple[str, ...], points: np.ndarray) -> dict[str, float]:
    """An entry's metrics dict (keys in ``order``) from its point metrics (in the board's ``keys``)."""
    values = dict(zip(keys, points.tolist(), strict=True))
    return {k: values[k] for k in order}


def _public(
    shared: Any, packed: Any, completed: Any, metrics: dict[str, float] | None = None
) -> dict[str, Any]:
    """An entry's public fields (``boards.public_fields``) from what the board keeps of them: its
    submission's (``shared``) and its run's (``metrics``: when they are not among them)."""
    fields = _unpacked(shared) | _unpacked(packed)
    if metrics is not None:
        fields["metrics"] = metrics
    return {
        "submission_id": fields["submission_id"],
        "name": fields["name"],
        "participant": fields["participant"],
        "baseline": fields["baseline"],
        "metrics": fields["metrics"],
        "extras": fields["extras"],
        "completed_at": completed,
        "verification": fields["verification"],
    }


def _times(
    values: Sequence[Any], code: Callable[[Any], int]
) -> tuple[np.ndarray, np.ndarray, dict[int, Any]]:
    """Finish times as arrays: the wall time as datetime64[us] (NaT: none) and the time zone coded by
    ``code`` — 12 bytes an entry where a datetime object took 56 (a database's times share one zone
    object). By position, those the arrays would not give back as they were (another type; a time in a
    repeated hour, ``fold``), kept as they are. A datetime comes back equal, its zone the same object."""
    micros: list[int] = []  # wall time, µs since 1970-01-01 (numpy's datetime64[us] as an integer)
    zones: list[int] = []
    odd: dict[int, Any] = {}
    offsets: dict[Any, int] = {}  # a fixed-offset zone's offset in µs
    for k, value in enumerate(values):
        if type(value) is datetime and not value.fold:
            zone = value.tzinfo
            # datetime arithmetic, not numpy's conversion of datetime objects (5 µs each: 2.6 % of a start);
            # an aware time less the epoch is UTC, so a fixed offset is added back for the wall time
            if zone is None:
                micros.append((value - _EPOCH) // _MICROSECOND)
            elif type(zone) is timezone:
                shift = offsets.get(zone)
                if shift is None:
                    shift = offsets[zone] = zone.utcoffset(None) // _MICROSECOND
                micros.append((value - _EPOCH_UTC) // _MICROSECOND + shift)
            else:  # a zone whose offset moves (DST): the wall time itself
                micros.append((value.replace(tzinfo=None) - _EPOCH) // _MICROSECOND)
            zones.append(code(zone))
        else:
            micros.append(_NAT)
            zones.append(code(None))
            if value is not None:
                odd[k] = value
    at = np.array(micros, dtype=np.int64).reshape(len(values)).view("datetime64[us]")
    return at, np.array(zones, dtype=np.int32).reshape(len(values)), odd


_EPOCH = datetime(1970, 1, 1)
_EPOCH_UTC = datetime(1970, 1, 1, tzinfo=UTC)
_MICROSECOND = timedelta(microseconds=1)
_NAT = int(np.iinfo(np.int64).min)  # numpy's NaT


def _time(at: np.datetime64, zone: Any, odd: Any = None) -> Any:
    """A finish time :func:`_times` kept (``zone``: its decoded zone; ``odd``: the one kept beside)."""
    if odd is not None:
        return odd
    if np.isnat(at):
        return None
    wall = at.item()  # datetime64[us] gives a datetime back
    return wall.replace(tzinfo=zone) if isinstance(wall, datetime) else wall


def _unpacked(packed: Any) -> dict[str, Any]:
    return orjson.loads(packed) if isinstance(packed, bytes) else dict(packed)


def _same_or(old: Any, new: Any) -> Any:
    """``old`` when ``new`` packs the same fields (:func:`_packed`), else ``new``: what is kept stays one object."""
    return old if old is not None and type(old) is type(new) and old == new else new


def _packed(public: dict[str, Any]) -> Any:
    """Public fields as compact JSON (≈ 0.4 kB where their dicts took ≈ 1.7 kB), or as they are when JSON
    would not give them back equal (a non-finite float, a key that is not a string)."""
    try:
        body = orjson.dumps(public)
    except TypeError:
        return public
    # a copy: orjson's bytes keep the 4 kB buffer they were written into
    return bytes(memoryview(body)) if orjson.loads(body) == public else public


#: The last serial number handed out (rows and entry versions: unique in the process).
_LAST_SERIAL = [0]


def new_serials(n: int) -> np.ndarray:
    """``n`` new serial numbers (of rows: the grid's too)."""
    first = _LAST_SERIAL[0] + 1
    _LAST_SERIAL[0] += n
    return np.arange(first, first + n, dtype=np.int64)


#: What a row shows of its submission beside its run's metrics and extras (``boards.public_fields``).
_PUBLIC = ("submission_id", "name", "participant", "baseline", "verification")


def _scoring_fields(row: Mapping[str, Any]) -> int:
    """What of a row its scoring depends on (a verdict or name changing moves no score), as a hash (of this
    process: only compared with what the board kept)."""
    fields = (row.get("metrics"), row.get("extras"), row.get("submission_status"))
    try:
        body = orjson.dumps(fields, option=orjson.OPT_NON_STR_KEYS)
    except TypeError:
        body = repr(fields).encode()
    return hash((body, row.get("ids")))


#: Odd multipliers of :func:`_row_hashes`, one per column a row shows.
_MIX = np.random.default_rng(20_251_129).integers(0, 2**63, size=64, dtype=np.uint64) * np.uint64(
    2
) + np.uint64(1)


def _row_hashes(shown: np.ndarray) -> np.ndarray:
    """A 64-bit hash per row of what rows show (rows × columns, float64; NaN = NaN): the sum of each value's
    bits times an odd number per column, modulo 2**64. A change of one value always changes it (an odd factor
    is invertible); of several, by a 2**-64 chance. 8 bytes an entry where the figures took 136."""
    canonical = np.where(np.isnan(shown), np.nan, shown + 0.0)  # one NaN; -0.0 and 0.0 alike
    with np.errstate(over="ignore"):
        bits = canonical.view(np.uint64) * _MIX[: shown.shape[1]]
    hashes: np.ndarray = np.add.reduce(bits, axis=1, dtype=np.uint64)
    return hashes


def _point(value: object) -> float:
    if isinstance(value, int | float) and not isinstance(value, bool) and np.isfinite(value):
        return float(value)
    return np.nan


def _points_of(metrics: Sequence[Mapping[str, Any]], keys: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Entries' point metrics (entries × ``keys``, NaN where missing, not a number or not finite) and whether
    each entry's metrics are exactly those points (its keys are ``keys``, every value a finite float: then
    they need not be kept beside them). Values that are all floats, the common case, are taken as they are."""
    rows: list[list[Any]] = []
    exact: list[bool] = []
    for m in metrics:
        values = [m.get(k) for k in keys]
        if all(type(v) is float for v in values):
            rows.append(values)
            exact.append(len(m) == len(keys))
        else:
            rows.append([_point(v) for v in values])
            exact.append(False)
    points = np.array(rows, dtype=np.float64).reshape(len(metrics), len(keys))
    finite = np.isfinite(points)
    points[~finite] = np.nan
    return points, np.array(exact, dtype=bool).reshape(len(metrics)) & finite.all(axis=1)


def _order_and_interval(rel: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Each row's (entries, resamples; no NaN) four order statistics the percentile interval interpolates
    between (``stats.order_statistics``), and the interval (``stats.interval``: the same formula, so the same
    bits)."""
    r = rel.shape[1]
    tail = (1.0 - stats.CONFIDENCE) / 2.0
    positions = [q * max(r - 1, 0) for q in (tail, 1.0 - tail)]
    pairs = [(int(np.floor(p)), min(int(np.floor(p)) + 1, max(r - 1, 0))) for p in positions]
    order = stats.order_statistics(rel, [k for pair in pairs for k in pair])
    ends = [
        order[:, 2 * i] + (order[:, 2 * i + 1] - order[:, 2 * i]) * (position - pairs[i][0])
        for i, position in enumerate(positions)
    ]
    return order, (ends[0], ends[1])


def _side(values: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Where each value lies against an entry's order statistics (entries, 4): 0 below the first, 1
    strictly between the second and the third, 2 above the fourth, -1 on or between a pair (undecided)."""
    out = np.full(values.shape, -1, dtype=np.int8)
    out[values < order[:, 0:1]] = 0
    out[(values > order[:, 1:2]) & (values < order[:, 2:3])] = 1
    out[values > order[:, 3:4]] = 2
    return out


def _fmin(lo: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """Per resample and metric (resamples, metrics), the lower of ``lo`` and the entries' (metrics, entries,
    resamples) samples (NaN = nobody measured)."""
    if samples.shape[1] == 0:
        return lo
    low = np.fmin.reduce(samples, axis=1).T
    return np.asarray(low if lo.size == 0 else np.fmin(lo, low))


def _fmax(hi: np.ndarray, samples: np.ndarray) -> np.ndarray:
    if samples.shape[1] == 0:
        return hi
    high = np.fmax.reduce(samples, axis=1).T
    return np.asarray(high if hi.size == 0 else np.fmax(hi, high))


def _fold(low: np.ndarray, high: np.ndarray, part: np.ndarray) -> None:
    """Fold a tile's samples (metrics, entries, resamples; each metric's rows contiguous) into running minima and
    maxima (metrics, resamples; NaN: nobody measured yet), as ``numpy.fmin`` and ``fmax``: in one compiled pass
    where the kernels are built (numpy's reductions made two)."""
    if compiled is None:  # numpy's reductions (``_fmin``, ``_fmax``: resamples × metrics)
        low[...], high[...] = _fmin(low.T, part).T, _fmax(high.T, part).T
        return
    for j in range(part.shape[0]):
        compiled.fold_min_max(part[j], low[j], high[j])


def _same_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per resample, whether two min (or max) arrays agree on every metric (NaN = NaN)."""
    return np.asarray(np.all((a == b) | (np.isnan(a) & np.isnan(b)), axis=1))
