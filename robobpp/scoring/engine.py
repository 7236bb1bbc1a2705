"""A board kept between updates: only the global part of the scoring is redone when entries arrive.

Each entry's own part (its figures as a matrix, metric and stable intervals: :mod:`robobpp.scoring.entries`)
was computed when its run finished. What an arriving entry can change on a board is global:

* the min–max of each metric in each resample (the relative score's normalisation). The board keeps them
  (resamples × metrics). When a new entry lies inside them in every resample — the common case — no other
  entry's relative score samples move: only the new entry's samples, score interval and the point ranks
  are computed. When it moves one (a new best or worst), or an entry leaves, or the board's groups change,
  every entry's samples are renormalised (from the figures the board keeps: :class:`~robobpp.scoring.entries.PartTable`).
* ranks and rank intervals. Point ranks and the best entries' rank intervals (the default view, one
  entry per participant) are recomputed on every update. The all-entries rank intervals need every entry's
  rank in every resample (a sort of each resample: seconds at 10,000 entries, BENCHMARKS.md): they are
  computed by a full computation (``rank_intervals=True``, the board worker's refresh timer); between two,
  an entry keeps the interval last computed and a new entry has none (served as null).

The board produced equals :func:`robobpp.scoring.boards.build_board` of the same rows (to the last bit of
each entry's own samples: an entry's samples are always computed alone), except for those rank intervals.
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robobpp.scoring import stats
from robobpp.scoring.boards import (
    GRID_RESAMPLES,
    LazyRows,
    RankedView,
    best_of_participants,
    board_dict,
    board_tops,
    classify_row,
    participant_key,
    public_fields,
)
from robobpp.scoring.entries import (
    EntryPart,
    PartTable,
    counts,
    metric_keys,
    samples_of,
    stable_samples,
    with_timing_noise,
)
from robobpp.scoring.scores import RESOLVED, WEIGHTS, competition_ranks, min_max, stable_scores

#: Loads the stored parts of a board's entries by submission id (None: the run has no figures).
PartLoader = Callable[[Sequence[int]], Mapping[int, EntryPart | None]]
#: Entries renormalised at a time (bounds the transient samples array: chunk × resamples × metrics).
CHUNK = 512


@dataclass(slots=True)
class _Scored:
    """What a board keeps of one ranked entry between updates (valid under the board's current min–max)."""

    order: np.ndarray  # (4,): the order statistics its score interval interpolates between
    score_ci: tuple[float, float]
    stable_ci: tuple[float, float]
    intervals: dict[str, list[float] | None]
    #: float32 (GRID_RESAMPLES,): its relative and stable score samples for the grid, while they are its own
    #: (computed or changed since the board was last assembled); None: row ``col`` of the board's matrices
    rel: np.ndarray | None
    stable: np.ndarray | None
    rank_ci: tuple[int, int] | None = None
    col: int = -1


@dataclass(slots=True)
class _Entry:
    """One candidate row of the board, with what its scoring needs decoded once."""

    row: dict[str, Any]
    episodes: int
    policy_failed: bool
    submission_failed: bool
    who: str
    sid: int
    points: np.ndarray  # (metrics,) point figures, NaN = missing
    stable: float  # the point stable score (its own metrics alone)
    ids: bytes | None
    public: dict[str, Any]
    scored: _Scored | None = None
    normalized: tuple[bytes, dict[str, float]] | None = None
    #: The entry as served in the all-entries view without its rank, and what it was built from: the same
    #: object while its content stays, so the publisher serialises it once (services/boards.py).
    base: dict[str, Any] | None = None
    base_of: tuple[Any, ...] = ()
    #: Changes whenever ``base`` is replaced (the grid compares its cells' serials as arrays)
    serial: int = 0


class BoardMatrix:
    """One board (dataset × setting × protocol × lookahead of a track) kept between updates.

    ``rows`` are what :func:`robobpp.db.queries.board_runs` returns without ``entry``, with ``ids``: the
    run's group ids as bytes (None without figures). ``load`` reads stored parts by submission id (only for
    rows upserted without theirs).
    """

    def __init__(
        self, dataset: str, setting: str, track: str, protocol: str, load: PartLoader, lookahead: int = 0
    ) -> None:
        if setting not in WEIGHTS:
            raise ValueError(f"unknown setting {setting!r}; expected one of {', '.join(WEIGHTS)}")
        self.dataset, self.setting, self.track, self.protocol = dataset, setting, track, protocol
        self.lookahead = lookahead
        self.load = load
        self.keys = metric_keys(setting)
        #: Per metric, the floor of its min–max (``scores.RESOLVED``): the bounds kept are floored, so an entry
        #: whose time moves only below the floor moves no bound (nobody is renormalised for it)
        self._floors = np.array([RESOLVED[k][0] if k in RESOLVED else -np.inf for k in self.keys])
        self._weights = np.array([WEIGHTS[setting][k] for k in self.keys])
        self._entries: dict[int, _Entry] = {}
        #: Every entry's part with figures, as matrices (an entry that moves a resample's min or max
        #: renormalises the others from them, never from SQL)
        self._parts = PartTable(setting)
        self._basis: tuple[Any, ...] | None = None
        self._lo = self._hi = np.zeros((0, 0))
        #: The grid samples of the last assembled board, an entry per row (its ``_Scored.col``): kept as two
        #: matrices, not an array per entry (10,000 arrays stacked again on every update cost 0.1 s a board)
        self._grid_rel = self._grid_stable = np.zeros((0, GRID_RESAMPLES), np.float32)
        #: Bumped whenever entries already on the board were renormalised (a resample's min–max moved).
        self.epoch = 0
        #: Counters of what updates did (BENCHMARKS.md): renormalised rows, entries recomputed in full.
        self.shifted_rows = 0
        self.recomputed = 0

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, submission_id: object) -> bool:
        return submission_id in self._entries

    def submission_ids(self) -> list[int]:
        return list(self._entries)

    def apply(
        self,
        upsert: Iterable[Mapping[str, Any]] = (),
        remove: Iterable[int] = (),
        parts: Mapping[int, EntryPart | None] | None = None,
    ) -> None:
        """Add or replace rows (``parts``: their parts when already at hand), drop submissions."""
        for sid in remove:
            if self._entries.pop(sid, None) is not None:
                self._basis = None  # it may have held a min or max: renormalise everyone
            self._parts.drop(sid)
        upsert = list(upsert)
        given = dict(parts or {})
        lacking = [int(r["submission_id"]) for r in upsert if int(r["submission_id"]) not in given]
        if lacking:  # its part may have changed: read it again
            given.update(self.load(lacking))
        for sid in given:  # a part of None: the run has no figures any more
            self._parts.drop(sid)
        self._parts.put_many({sid: part for sid, part in given.items() if part is not None})
        for row in upsert:
            sid = int(row["submission_id"])
            old = self._entries.get(sid)
            entry = self._entry(row)
            if old is not None:
                if _scoring_fields(old.row) == _scoring_fields(row):
                    entry.scored, entry.normalized = old.scored, old.normalized
                else:
                    self._basis = None
            self._entries[sid] = entry

    def _entry(self, row: Mapping[str, Any]) -> _Entry:
        extras = row.get("extras") or {}
        episodes = int(extras.get("episodes") or row.get("episodes_total") or 0)
        metrics = row.get("metrics") or {}
        return _Entry(
            row={k: row.get(k) for k in _KEPT},
            episodes=episodes,
            policy_failed=stats.run_failed(extras.get("terminations"), episodes),
            submission_failed=row.get("submission_status") == "failed",
            who=participant_key(row),
            sid=int(row["submission_id"]),
            points=np.array([_point(metrics.get(k)) for k in self.keys], dtype=np.float64),
            stable=stable_scores([metrics], self.setting)[0],
            ids=row.get("ids"),
            public=public_fields(row),
        )

    def board(self, *, rank_intervals: bool = False) -> dict[str, Any]:
        """The board now (``rank_intervals``: compute every entry's, a full computation)."""
        everyone = [self._entries[s] for s in sorted(self._entries)]
        groups = max((e.episodes for e in everyone if not e.policy_failed), default=0)
        ranked = [e for e in everyone if not (e.policy_failed or e.submission_failed or e.episodes < groups)]
        submitted = Counter(e.who for e in everyone)
        ids = next((e.ids for e in ranked if e.ids is not None), None)
        plan = counts(len(ids) // 8) if ids else np.ones((stats.RESAMPLES, 1))
        usable = np.array([e.ids is not None and e.ids == ids for e in ranked], dtype=bool)
        basis = (groups, ids, plan.shape)
        fresh = [i for i, e in enumerate(ranked) if e.scored is None]
        full = (
            rank_intervals
            or self._basis != basis
            or len(ranked) - len(fresh) != sum(e.scored is not None for e in everyone)
        )
        rel_all = None
        if not full and fresh:
            new = self._samples([ranked[i] for i in fresh], usable[fresh], plan)
            lo, hi = self._floored(_fmin(self._lo, new)), self._floored(_fmax(self._hi, new))
            moved = np.flatnonzero(~_same_rows(lo, self._lo) | ~_same_rows(hi, self._hi))
            if moved.size:
                old = [i for i, e in enumerate(ranked) if e.scored is not None]
                self._shift(moved, lo, hi, [ranked[i] for i in old], usable[old], plan)
            self._score(new, [ranked[i] for i in fresh], usable[fresh])
        elif full:
            chosen = {id(e) for e in ranked}
            for e in everyone:
                if id(e) not in chosen:
                    e.scored = None
            rel_all = self._renormalise(ranked, usable, plan, keep=rank_intervals)
            self._basis = basis
            self.epoch += 1
        if rel_all is not None and rank_intervals and ranked:
            low, high = stats.rank_interval(stats.rank_samples(rel_all))
            for k, e in enumerate(ranked):
                assert e.scored is not None
                e.scored.rank_ci = (int(low[k]), int(high[k]))

        def best_samples(chosen: list[int]) -> np.ndarray:
            if rel_all is not None:
                return rel_all[:, chosen].astype(np.float32)
            samples = self._samples([ranked[i] for i in chosen], usable[chosen], plan)
            return self._relative(samples, self._lo, self._hi).T.astype(np.float32)

        return self._assemble(everyone, ranked, groups, submitted, best_samples)

    # -- the parts of the computation

    def _samples(
        self, entries: Sequence[_Entry], usable: np.ndarray, plan: np.ndarray, rows: np.ndarray | None = None
    ) -> np.ndarray:
        """Entries' metric samples: (entries, resamples, metrics), with their timing noise; an entry without
        usable figures keeps its point metrics in every resample (as ``score_board`` does). ``plan`` is the
        rows ``rows`` of the board's plan (default: all of it)."""
        sids = [e.sid for e in entries]
        out = np.empty((len(entries), plan.shape[0], len(self.keys)))
        measured = [k for k, ok in enumerate(usable) if ok]
        seeds: list[int | None] = [None] * len(entries)
        if measured:
            if any(sids[k] not in self._parts for k in measured):
                raise ValueError(f"{self.dataset}/{self.setting}: an entry with group ids has no stored part")
            top, bottom = self._parts.stacked([sids[k] for k in measured])
            out[measured] = samples_of(top, bottom, plan)
            for k in measured:
                seeds[k] = self._parts.seed(sids[k])
        for k, ok in enumerate(usable):
            if not ok:
                out[k] = entries[k].points
        return with_timing_noise(out, seeds, self.setting, rows)

    def _floored(self, bounds: np.ndarray) -> np.ndarray:
        """Per resample and metric, a min or max as the normalisation uses it (``scores.min_max``: NaN stays)."""
        return np.maximum(bounds, self._floors) if bounds.size else bounds

    def _relative(self, samples: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Relative score samples (entries, resamples) under a min–max (``scores._min_max_rows``)."""
        total = np.zeros(samples.shape[:2])
        for j, weight in enumerate(self._weights):
            total += weight * min_max(samples[:, :, j], lo[:, j], hi[:, j], self.keys[j])
        return np.round(total, 12)

    def _score(self, samples: np.ndarray, entries: Sequence[_Entry], usable: np.ndarray) -> np.ndarray:
        """Store the entries' scored part under the current min–max; returns their relative samples.

        An entry's metric and stable intervals are its stored part's (computed when its run finished);
        one without usable figures has point metrics in every resample, so no metric interval."""
        rel = self._relative(samples, self._lo, self._hi)
        stab = stable_samples(samples, self.setting)
        order, (lo, hi) = _order_and_interval(rel)
        for k, entry in enumerate(entries):
            if usable[k] and entry.sid in self._parts:
                metric_ci, stable_ci = self._parts.intervals(entry.sid)
                intervals = {
                    key: [float(a), float(b)] if np.isfinite(a) else None
                    for key, (a, b) in zip(self.keys, metric_ci.tolist(), strict=True)
                }
            else:
                intervals = dict.fromkeys(self.keys)
                slo, shi = stats.interval(stab[k][:, None])
                stable_ci = (float(slo[0]), float(shi[0]))
            rank_ci = None if entry.scored is None else entry.scored.rank_ci
            entry.scored = _Scored(
                order=order[k],
                score_ci=(float(lo[k]), float(hi[k])),
                stable_ci=stable_ci,
                intervals=intervals,
                rel=rel[k, :GRID_RESAMPLES].astype(np.float32),
                stable=stab[k, :GRID_RESAMPLES].astype(np.float32),
                rank_ci=rank_ci,
            )
        self.recomputed += len(entries)
        return rel

    def _shift(
        self,
        moved: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        entries: Sequence[_Entry],
        usable: np.ndarray,
        plan: np.ndarray,
    ) -> None:
        """A new entry moved the min or max of the resamples ``moved``: only those resamples of every other
        entry change. An entry whose changed samples stay on the same side of each order statistic its score
        interval uses keeps that interval (those statistics cannot move); the others are recomputed."""
        pad = (-moved.size) % 8  # the matrix product gives the same bits as the full one in blocks of 8 rows
        rows = np.concatenate([moved, np.zeros(pad, dtype=moved.dtype)])
        samples = self._samples(entries, usable, plan[rows], rows)[:, : moved.size]
        before = self._relative(samples, self._lo[moved], self._hi[moved])
        after = self._relative(samples, lo[moved], hi[moved])
        order = np.stack([e.scored.order for e in entries if e.scored is not None])
        side_before, side_after = _side(before, order), _side(after, order)
        kept = np.all((side_before == side_after) & (side_before >= 0), axis=1)
        grid_rows = moved < GRID_RESAMPLES
        self._lo, self._hi = lo, hi
        redo = [k for k in range(len(entries)) if not kept[k]]
        if grid_rows.any():  # only the grid's resamples are kept per entry
            changed = after[:, grid_rows].astype(np.float32)
            for k in np.flatnonzero(kept).tolist():
                scored = entries[k].scored
                assert scored is not None
                if scored.rel is None:  # its row of the published board stays as it was: changed in a copy
                    scored.rel = self._grid_rel[scored.col].copy()
                    scored.stable = self._grid_stable[scored.col].copy()
                scored.rel[moved[grid_rows]] = changed[k]
        for a in range(0, len(redo), CHUNK):
            chunk = [entries[k] for k in redo[a : a + CHUNK]]
            ok = usable[redo[a : a + CHUNK]]
            self._score(self._samples(chunk, ok, plan), chunk, ok)
        self.shifted_rows += int(moved.size)
        self.epoch += 1

    def _renormalise(
        self, ranked: list[_Entry], usable: np.ndarray, plan: np.ndarray, *, keep: bool
    ) -> np.ndarray | None:
        """Every entry's samples again: the min–max first, then each entry scored under it. Returns every
        entry's relative samples (resamples, entries) when ``keep``."""
        m = len(self.keys)
        lo = np.full((plan.shape[0], m), np.nan)
        hi = np.full((plan.shape[0], m), np.nan)
        for a in range(0, len(ranked), CHUNK):
            chunk = self._samples(ranked[a : a + CHUNK], usable[a : a + CHUNK], plan)
            lo, hi = _fmin(lo, chunk), _fmax(hi, chunk)
        self._lo, self._hi = self._floored(lo), self._floored(hi)
        rel_all = np.empty((plan.shape[0], len(ranked))) if keep else None
        for a in range(0, len(ranked), CHUNK):
            chunk_entries = ranked[a : a + CHUNK]
            chunk = self._samples(chunk_entries, usable[a : a + CHUNK], plan)
            rel = self._score(chunk, chunk_entries, usable[a : a + CHUNK])
            if rel_all is not None:
                rel_all[:, a : a + len(chunk_entries)] = rel.T
        return rel_all

    def _points(
        self, ranked: Sequence[_Entry]
    ) -> tuple[list[float], list[int], list[dict[str, float]], np.ndarray]:
        """Point scores, competition ranks and normalised metrics (``scores.score_entries``, vectorised:
        the same operations in the same order, so the same numbers)."""
        n = len(ranked)
        points = np.array([e.points for e in ranked]).reshape(n, len(self.keys))
        total = np.zeros(n)
        norm = np.zeros_like(points)
        bounds = []
        for j, weight in enumerate(self._weights):
            col = points[:, j]
            present = np.isfinite(col)
            if present.any():
                lo, hi = col[present].min(), col[present].max()
                norm[:, j] = min_max(col, lo, hi, self.keys[j])
                bounds += [lo, hi]
            total += weight * norm[:, j]
        scores = [round(x, 12) for x in total.tolist()]  # as score_entries: ties must tie
        key = np.array(bounds).tobytes()
        normalized = []
        rows = None
        for k, e in enumerate(ranked):
            known = e.normalized
            if known is None or known[0] != key:
                if rows is None:
                    rows = norm.tolist()
                known = e.normalized = (key, dict(zip(self.keys, rows[k], strict=True)))
            normalized.append(known[1])
        return scores, competition_ranks(scores), normalized, points

    def _assemble(
        self,
        everyone: list[_Entry],
        ranked: list[_Entry],
        groups: int,
        submitted: Counter[str],
        best_samples: Callable[[list[int]], np.ndarray],
    ) -> dict[str, Any]:
        """The board dict, as ``boards.assemble_board`` makes it."""
        ranked_ids = {id(e) for e in ranked}
        unranked = []
        for e in everyone:
            if id(e) not in ranked_ids:
                status, reason = classify_row(e.row, groups)
                unranked.append(
                    {**e.public, "status": status, "reason": reason, "entries_submitted": submitted[e.who]}
                )
        unranked.sort(key=lambda e: (e["status"], e["submission_id"]))
        scores, ranks, normalized, points = self._points(ranked)
        n = len(ranked)
        sids = np.fromiter((e.sid for e in ranked), dtype=np.int64, count=n)
        rank_of = np.asarray(ranks, dtype=np.int64).reshape(n)
        best_of = best_of_participants((e.who for e in ranked), sids, rank_of, scores, best_samples)
        chosen = sorted(best_of)
        bases: list[dict[str, Any]] = []
        serials = np.empty(n, dtype=np.int64)
        for i, e in enumerate(ranked):  # 150,000 entries an update: the unchanged row found inline
            s, of, is_best = e.scored, e.base_of, i in best_of
            if not (
                of
                and of[0] is s
                and of[2] is normalized[i]
                and of[1] == scores[i]
                and of[3] == is_best
                and of[4] == s.rank_ci
            ):
                before = e.base
                if _base(e, scores[i], normalized[i], is_best) is not before:
                    e.serial = next(_SERIALS)
            bases.append(e.base)  # type: ignore[arg-type]
            serials[i] = e.serial
        order = np.lexsort((sids, rank_of))  # rank order, ties by id
        view = RankedView(sids[order], rank_of[order], sids, rank_of, bases, serials)

        def listed(i: int) -> dict[str, Any]:
            """Column ``i`` as the all-entries view lists it (``boards.finish_board``'s entry)."""
            d = bases[i] | {"rank": ranks[i], "entries_submitted": submitted[ranked[i].who], "_column": i}
            b = best_of.get(i)
            if b is not None:
                d["best_rank"], d["best_rank_low"], d["best_rank_high"] = b
            return d

        at = order.tolist()
        entries = LazyRows(lambda: [listed(i) | {"_base": bases[i]} for i in at])
        best = [listed(i) | {"rank": b[0], "rank_low": b[1], "rank_high": b[2]} for i, b in best_of.items()]
        best.sort(key=lambda e: (e["rank"], e["submission_id"]))
        samples, stable = self._grid_matrices(ranked)
        by_column = np.array([scores, [e.stable for e in ranked]], dtype=np.float64).reshape(2, n)
        board = board_dict(
            self.dataset,
            self.setting,
            self.track,
            groups,
            entries,
            unranked,
            best,
            samples,
            stable,
            by_column,
            index=dict(zip(view.ids.tolist(), range(n), strict=True)),
            tops={
                "best": board_tops(np.asarray(scores)[chosen], points[chosen], self.keys),
                "all": board_tops(np.asarray(scores), points, self.keys),
            },
        )
        board["protocol"] = self.protocol
        board["lookahead"] = self.lookahead
        board["_ranked"] = view
        # the board's matrices are the kept ones (``board_dict`` turns the transposed views back into the
        # row-per-entry matrices built here, no copy); read-only: a shift changes an entry's samples in a copy
        self._grid_rel, self._grid_stable = board["_samples"], board["_stable_samples"]
        self._grid_rel.flags.writeable = self._grid_stable.flags.writeable = False
        return board

    def _grid_matrices(self, ranked: Sequence[_Entry]) -> tuple[np.ndarray, np.ndarray]:
        """The ranked entries' grid samples as two (GRID_RESAMPLES, entries) matrices (``board_dict`` keeps
        them transposed): the rows of the last ones gathered at once, an entry's own samples put in; each
        entry then refers to its new row."""
        n = len(ranked)
        scored = [e.scored for e in ranked if e.scored is not None]
        if len(scored) != n:
            raise AssertionError("an entry on the board is not scored")
        own = [k for k, s in enumerate(scored) if s.rel is not None]
        # as many resamples as the entries' own samples (a plan may have fewer than GRID_RESAMPLES), else as before
        size = len(scored[own[0]].rel) if own else self._grid_rel.shape[1]  # type: ignore[arg-type]
        rel = np.empty((n, size), np.float32)
        stable = np.empty((n, size), np.float32)
        if len(own) < n:
            at = np.ones(n, dtype=bool)
            at[own] = False
            rows = np.fromiter((s.col for s in scored if s.rel is None), dtype=np.intp, count=n - len(own))
            rel[at] = self._grid_rel[rows]
            stable[at] = self._grid_stable[rows]
        for k in own:
            rel[k], stable[k] = scored[k].rel, scored[k].stable
        for k, s in enumerate(scored):
            s.rel = s.stable = None
            s.col = k
        return rel.T, stable.T


def _base(entry: _Entry, score: float, normalized: dict[str, float], best: bool) -> dict[str, Any]:
    """The entry's all-entries row without its rank (nor its participant's entry count, which moves with
    every entry they add: the reader puts it in): the object kept from the last update when nothing it shows
    moved (an arriving entry moves the ranks below it and nothing else of theirs). An entry scored again
    (a shift renormalised it) keeps its row when its figures came out the same."""
    s = entry.scored
    assert s is not None
    old = entry.base_of
    if (
        entry.base is None
        or old[2] is not normalized
        or old[1] != score
        or old[3] != best
        or s.rank_ci != old[4]
        or (old[0] is not s and not _same_figures(old[0], s))
    ):
        entry.base = {
            **entry.public,
            "rank": None,
            "rank_low": None if s.rank_ci is None else s.rank_ci[0],
            "rank_high": None if s.rank_ci is None else s.rank_ci[1],
            "score": score,
            "score_low": s.score_ci[0],
            "score_high": s.score_ci[1],
            "stable": entry.stable,
            "stable_low": s.stable_ci[0],
            "stable_high": s.stable_ci[1],
            "normalized": normalized,
            "intervals": s.intervals,
            "best": best,
        }
    entry.base_of = (s, score, normalized, best, s.rank_ci)
    return entry.base


def _same_figures(a: _Scored, b: _Scored) -> bool:
    """Whether two scorings of an entry show the same figures (its row would not change)."""
    return a.score_ci == b.score_ci and a.stable_ci == b.stable_ci and a.intervals == b.intervals


def _order_and_interval(rel: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Each row's (entries, resamples; no NaN) four order statistics the percentile interval interpolates
    between, and the interval (``stats.interval``: the same formula, so the same bits)."""
    r = rel.shape[1]
    tail = (1.0 - stats.CONFIDENCE) / 2.0
    ordered = np.sort(rel, axis=1)
    picks, ends = [], []
    for q in (tail, 1.0 - tail):
        position = q * np.maximum(np.full(rel.shape[0], r) - 1, 0)
        below = np.floor(position).astype(np.intp)
        above = np.minimum(below + 1, np.maximum(r - 1, 0))
        low = np.take_along_axis(ordered, below[:, None], axis=1)[:, 0]
        high = np.take_along_axis(ordered, above[:, None], axis=1)[:, 0]
        picks += [low, high]
        ends.append(low + (high - low) * (position - below))
    return np.stack(picks, axis=1), (ends[0], ends[1])


def _side(values: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Where each value lies against an entry's order statistics (entries, 4): 0 below the first, 1
    strictly between the second and the third, 2 above the fourth, -1 on or between a pair (undecided)."""
    out = np.full(values.shape, -1, dtype=np.int8)
    out[values < order[:, 0:1]] = 0
    out[(values > order[:, 1:2]) & (values < order[:, 2:3])] = 1
    out[values > order[:, 3:4]] = 2
    return out


#: Serial numbers of the entries' rows (:attr:`_Entry.serial`), unique in the process.
_SERIALS = itertools.count(1)

#: What an entry keeps of its row (its scoring fields, ``classify_row``'s and its id; what it shows is in
#: ``public``): the whole row again for each of 150,000 entries was ≈ 45 MB at 10,000 submissions.
_KEPT = ("submission_id", "metrics", "extras", "ids", "submission_status", "episodes_total")


def _scoring_fields(row: Mapping[str, Any]) -> tuple[Any, ...]:
    """What of a row its scoring depends on (a verdict or name changing moves no score)."""
    return (row.get("metrics"), row.get("extras"), row.get("ids"), row.get("submission_status"))


def _point(value: object) -> float:
    if isinstance(value, int | float) and not isinstance(value, bool) and np.isfinite(value):
        return float(value)
    return np.nan


def _fmin(lo: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """Per resample and metric, the lower of ``lo`` and the entries' samples (NaN = nobody measured)."""
    if samples.shape[0] == 0:
        return lo
    low = np.fmin.reduce(samples, axis=0)
    return low if lo.size == 0 else np.fmin(lo, low)


def _fmax(hi: np.ndarray, samples: np.ndarray) -> np.ndarray:
    if samples.shape[0] == 0:
        return hi
    high = np.fmax.reduce(samples, axis=0)
    return high if hi.size == 0 else np.fmax(hi, high)


def _same_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per resample, whether two min (or max) arrays agree on every metric (NaN = NaN)."""
    return np.all((a == b) | (np.isnan(a) & np.isnan(b)), axis=1)
