"""A board kept between updates: only the global part of the scoring is redone when entries arrive.

Each entry's own part (its figures as a matrix, metric and stable intervals: :mod:`robobpp.scoring.entries`)
was computed when its run finished. What an arriving entry can change on a board is global:

* the min–max of each metric in each resample (the relative score's normalisation). The board keeps them
  (resamples × metrics). When a new entry lies inside them in every resample — the common case — no other
  entry's relative score samples move: only the new entry's samples, score interval and the point ranks
  are computed. When it moves one (a new best or worst), or an entry leaves, or the board's groups change,
  every entry's samples are renormalised (:meth:`BoardMatrix.board` reloads the parts).
* ranks and rank intervals. Point ranks and the best entries' rank intervals (the default view, one
  entry per participant) are recomputed on every update. The all-entries rank intervals need every entry's
  rank in every resample (a sort of each resample: seconds at 10,000 entries, BENCHMARKS.md): they are
  computed by a full computation (``rank_intervals=True``, the board worker's refresh timer); between two,
  an entry keeps the interval last computed and a new entry has none (served as null).

The board produced equals :func:`robobpp.scoring.boards.build_board` of the same rows (to the last bit of
each entry's own samples: an entry's samples are always computed alone), except for those rank intervals.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robobpp.scoring import stats
from robobpp.scoring.boards import GRID_RESAMPLES, assemble_board, classify
from robobpp.scoring.entries import EntryPart, counts, metric_keys, samples_of, stable_samples
from robobpp.scoring.metrics import METRIC_BY_KEY
from robobpp.scoring.scores import WEIGHTS, BoardScores, score_entries, stable_scores

#: Loads the stored parts of a board's entries by submission id (None: the run has no figures).
PartLoader = Callable[[Sequence[int]], Mapping[int, EntryPart | None]]
#: Entries renormalised at a time (bounds the transient samples array: chunk × resamples × metrics).
CHUNK = 512


@dataclass(slots=True)
class _Scored:
    """What a board keeps of one ranked entry between updates (valid for the board's current basis)."""

    score_ci: tuple[float, float]
    stable_ci: tuple[float, float]
    metric_ci: dict[str, tuple[float, float] | None]
    rel: np.ndarray  # float32 (GRID_RESAMPLES,): relative score samples, for the grid
    stable: np.ndarray  # float32 (GRID_RESAMPLES,)
    rank_ci: tuple[int, int] | None


class BoardMatrix:
    """One board (dataset × setting × protocol of a track) kept between updates.

    ``rows`` are what :func:`robobpp.db.queries.board_rows` returns without ``figures``, with ``ids``: the
    run's group ids as bytes (None without figures). ``load`` reads parts when the board must renormalise.
    """

    def __init__(self, dataset: str, setting: str, track: str, protocol: str, load: PartLoader) -> None:
        if setting not in WEIGHTS:
            raise ValueError(f"unknown setting {setting!r}; expected one of {', '.join(WEIGHTS)}")
        self.dataset, self.setting, self.track, self.protocol = dataset, setting, track, protocol
        self.load = load
        self.rows: dict[int, dict[str, Any]] = {}
        self.keys = metric_keys(setting)
        self._parts: dict[int, EntryPart | None] = {}  # of new entries and the best ones
        self._basis: tuple[Any, ...] | None = None
        self._lo = self._hi = np.zeros((0, 0))
        self._scored: dict[int, _Scored] = {}
        #: Bumped whenever every entry's samples were renormalised (the grid's cache key).
        self.epoch = 0
        #: Whether every entry's rank interval is current (last :meth:`board` was a full computation).
        self.ranks_current = False

    def apply(
        self,
        upsert: Iterable[Mapping[str, Any]] = (),
        remove: Iterable[int] = (),
        parts: Mapping[int, EntryPart | None] | None = None,
    ) -> None:
        """Add or replace rows (``parts``: their parts when already at hand), drop submissions."""
        for sid in remove:
            self.rows.pop(sid, None)
            self._scored.pop(sid, None)
            self._parts.pop(sid, None)
            self._basis = None if self._basis is None else (*self._basis, "removed")
        for row in upsert:
            sid = int(row["submission_id"])
            old = self.rows.get(sid)
            self.rows[sid] = dict(row)
            if old is not None and _scoring_fields(old) != _scoring_fields(row):
                self._scored.pop(sid, None)
                self._basis = None if self._basis is None else (*self._basis, "changed")
        for sid, part in (parts or {}).items():
            self._parts[sid] = part

    def board(self, *, rank_intervals: bool = False) -> dict[str, Any]:
        """The board now (``rank_intervals``: compute every entry's, a full computation)."""
        rows = [self.rows[s] for s in sorted(self.rows)]
        sorted_out = classify(rows)
        ranked = sorted_out.ranked
        sids = [int(r["submission_id"]) for r in ranked]
        ids = next((r["ids"] for r in ranked if r.get("ids") is not None), None)
        plan = counts(len(ids) // 8) if ids else np.ones((stats.RESAMPLES, 1))
        usable = np.array([r.get("ids") is not None and r["ids"] == ids for r in ranked], dtype=bool)
        points = np.array([_points(r.get("metrics") or {}, self.keys) for r in ranked]).reshape(
            len(ranked), len(self.keys)
        )
        basis = (sorted_out.groups, ids)
        full = rank_intervals or self._basis != basis or not set(self._scored) <= set(sids)
        fresh = [i for i, s in enumerate(sids) if s not in self._scored]
        if not full and fresh:
            new = self._samples([sids[i] for i in fresh], usable[fresh], points[fresh], plan)
            lo, hi = _fmin(self._lo, new), _fmax(self._hi, new)
            if _same(lo, self._lo) and _same(hi, self._hi):
                self._score(new, [sids[i] for i in fresh], usable[fresh])
            else:
                full = True
        rel_all = None
        if full:
            rel_all = self._renormalise(sids, usable, points, plan, keep=rank_intervals)
            self._basis = basis
            self.epoch += 1
        self.ranks_current = rank_intervals
        if rel_all is not None and rank_intervals and sids:
            low, high = stats.rank_interval(stats.rank_samples(rel_all))
            for k, s in enumerate(sids):
                self._scored[s].rank_ci = (int(low[k]), int(high[k]))
        scores = self._board_scores(ranked, sids)

        def best_samples(chosen: list[int]) -> np.ndarray:
            if rel_all is not None:
                return rel_all[:, chosen].astype(np.float32)
            picked = [sids[i] for i in chosen]
            samples = self._samples(picked, usable[chosen], points[chosen], plan)
            return self._relative(samples).T.astype(np.float32)

        board = assemble_board(self.dataset, self.setting, self.track, sorted_out, scores, best_samples)
        board["protocol"] = self.protocol
        keep = {e["submission_id"] for e in board["_best"]}
        self._parts = {s: p for s, p in self._parts.items() if s in keep}
        return board

    # -- the parts of the computation

    def _samples(
        self, sids: Sequence[int], usable: np.ndarray, points: np.ndarray, plan: np.ndarray
    ) -> np.ndarray:
        """Entries' metric samples: (entries, resamples, metrics); an entry without usable figures keeps
        its point metrics in every resample (as ``score_board`` does)."""
        missing = [s for s, ok in zip(sids, usable, strict=True) if ok and s not in self._parts]
        if missing:
            self._parts.update(self.load(missing))
        out = np.empty((len(sids), plan.shape[0], len(self.keys)))
        rows = [k for k, ok in enumerate(usable) if ok]
        if rows:
            parts = [self._parts[sids[k]] for k in rows]
            if any(p is None for p in parts):
                raise ValueError(f"{self.dataset}/{self.setting}: an entry with group ids has no stored part")
            top = np.stack([p.top for p in parts if p is not None])
            bottom = np.stack([p.bottom for p in parts if p is not None])
            out[rows] = samples_of(top, bottom, plan)
        for k, ok in enumerate(usable):
            if not ok:
                out[k] = points[k]
        return out

    def _relative(self, samples: np.ndarray) -> np.ndarray:
        """Relative score samples (entries, resamples) under the board's min–max (``_min_max_rows``)."""
        total = np.zeros(samples.shape[:2])
        with np.errstate(invalid="ignore", divide="ignore"):
            for j, (key, weight) in enumerate(WEIGHTS[self.setting].items()):
                lo, hi = self._lo[:, j], self._hi[:, j]
                span = hi - lo
                s = samples[:, :, j]
                out = (s - lo) / span if METRIC_BY_KEY[key].better == "up" else (hi - s) / span
                total += weight * np.where(np.isfinite(out) & (span > 0), out, 0.0)
        return np.round(total, 12)

    def _score(self, samples: np.ndarray, sids: Sequence[int], usable: np.ndarray) -> np.ndarray:
        """Store the entries' scored part under the current min–max; returns their relative samples.

        An entry's metric and stable intervals are its stored part's (computed when its run finished);
        one without usable figures has point metrics in every resample, so no metric interval."""
        rel = self._relative(samples)
        stab = stable_samples(samples, self.setting)
        lo, hi = stats.interval(rel.T)
        for k, sid in enumerate(sids):
            part = self._parts.get(sid) if usable[k] else None
            if part is not None:
                metric_ci = {
                    key: (float(a), float(b)) if np.isfinite(a) else None
                    for key, (a, b) in zip(self.keys, part.metric_ci, strict=True)
                }
                stable_ci = part.stable_ci
            else:
                metric_ci = dict.fromkeys(self.keys)
                slo, shi = stats.interval(stab[k][:, None])
                stable_ci = (float(slo[0]), float(shi[0]))
            self._scored[sid] = _Scored(
                score_ci=(float(lo[k]), float(hi[k])),
                stable_ci=stable_ci,
                metric_ci=metric_ci,
                rel=rel[k, :GRID_RESAMPLES].astype(np.float32),
                stable=stab[k, :GRID_RESAMPLES].astype(np.float32),
                rank_ci=None,
            )
        return rel

    def _renormalise(
        self, sids: list[int], usable: np.ndarray, points: np.ndarray, plan: np.ndarray, *, keep: bool
    ) -> np.ndarray | None:
        """Every entry's samples again: the min–max first, then each entry scored under it. Returns every
        entry's relative samples (resamples, entries) when ``keep``."""
        self._parts.update(self.load([s for s, ok in zip(sids, usable, strict=True) if ok]))
        m = len(self.keys)
        lo = np.full((plan.shape[0], m), np.nan)
        hi = np.full((plan.shape[0], m), np.nan)
        for a in range(0, len(sids), CHUNK):
            chunk = self._samples(sids[a : a + CHUNK], usable[a : a + CHUNK], points[a : a + CHUNK], plan)
            lo, hi = _fmin(lo, chunk), _fmax(hi, chunk)
        self._lo, self._hi = lo, hi
        ranks_before = {s: self._scored[s].rank_ci for s in sids if s in self._scored}
        self._scored = {}
        rel_all = np.empty((plan.shape[0], len(sids))) if keep else None
        for a in range(0, len(sids), CHUNK):
            part = sids[a : a + CHUNK]
            chunk = self._samples(part, usable[a : a + CHUNK], points[a : a + CHUNK], plan)
            rel = self._score(chunk, part, usable[a : a + CHUNK])
            if rel_all is not None:
                rel_all[:, a : a + len(part)] = rel.T
        for s, ci in ranks_before.items():  # kept until the next full computation replaces them
            self._scored[s].rank_ci = ci
        return rel_all

    def _board_scores(self, ranked: Sequence[Mapping[str, Any]], sids: list[int]) -> BoardScores:
        metrics = [r.get("metrics") or {} for r in ranked]
        scored = [self._scored[s] for s in sids]
        n = len(sids)
        return BoardScores(
            scored=score_entries(metrics, self.setting),
            score_ci=[s.score_ci for s in scored],
            rank_ci=[s.rank_ci for s in scored],
            stable=stable_scores(metrics, self.setting),
            stable_ci=[s.stable_ci for s in scored],
            metric_ci=[s.metric_ci for s in scored],
            samples=np.stack([s.rel for s in scored], axis=1)
            if n
            else np.zeros((GRID_RESAMPLES, 0), np.float32),
            stable_samples=np.stack([s.stable for s in scored], axis=1)
            if n
            else np.zeros((GRID_RESAMPLES, 0), np.float32),
        )


def _scoring_fields(row: Mapping[str, Any]) -> tuple[Any, ...]:
    """What of a row its scoring depends on (a verdict or name changing moves no score)."""
    return (row.get("metrics"), row.get("extras"), row.get("ids"), row.get("submission_status"))


def _points(metrics: Mapping[str, Any], keys: Sequence[str]) -> list[float]:
    out = []
    for key in keys:
        v = metrics.get(key)
        if isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v):
            out.append(float(v))
        else:
            out.append(np.nan)
    return out


def _fmin(lo: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """Per resample and metric, the lower of ``lo`` and the entries' samples (NaN = nobody measured)."""
    if samples.shape[0] == 0:
        return lo
    with np.errstate(invalid="ignore"):
        low = np.fmin.reduce(samples, axis=0)
    return low if lo.size == 0 else np.fmin(lo, low)


def _fmax(hi: np.ndarray, samples: np.ndarray) -> np.ndarray:
    if samples.shape[0] == 0:
        return hi
    with np.errstate(invalid="ignore"):
        high = np.fmax.reduce(samples, axis=0)
    return high if hi.size == 0 else np.fmax(hi, high)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))
