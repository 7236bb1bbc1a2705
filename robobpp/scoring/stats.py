"""Uncertainty over groups: seeded bootstrap intervals, rank intervals and paired differences.

The unit of resampling is the *group* (one box sequence, one episode per dataset × setting): a board's
entries all ran the same groups, so one resample draws the same groups for every entry (a paired
bootstrap) and a run's figure is recomputed from the drawn groups exactly as it was aggregated
(means over episodes; the pooled ratios as ratios of sums, docs/benchmark.md, "Metrics").

Timing noise: a group bootstrap knows nothing of how finely a time was measured, so the scores' resamples
also move each entry's Decision Time by a uniform draw within the measurement's resolution
(:func:`timing_noise`, scaled by ``scores.timed``), independently per entry. The draw is seeded by the
entry's own per-group times (:func:`timing_seed`), so it is the same wherever and whenever the entry is
scored, and alone or among others.

Determinism: the resampling plan depends only on the number of groups, the number of resamples and a
fixed seed, so the same data gives the same interval on every machine and every read.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robobpp.scoring.kernels import compiled
from robobpp.scoring.metrics import POOLED, metrics_for

#: Resamples per interval; the ends of a 95 % percentile interval move by well under 1 % of its width
#: between seeds at this count.
RESAMPLES = 1000
#: Fixed seed of the resampling plan (part of the method: changing it is a new scoring version).
SEED = 20_251_117
CONFIDENCE = 0.95

#: Episode endings that are the policy's fault rather than a packing outcome: garbage or malformed
#: answers, errors, timeouts, protocol violations. A run with more than ``POLICY_FAILURE_SHARE`` of its
#: episodes ending so is *failed*: shown apart, never ranked, never in a normalisation.
POLICY_FAILURES = (
    "invalid_action",
    "policy_error",
    "policy_timeout",
    "protocol_violation",
    "episode_timeout",
)
POLICY_FAILURE_SHARE = 0.10


def policy_failure_count(terminations: Mapping[str, int] | None) -> int:
    return sum(int(n) for reason, n in (terminations or {}).items() if reason in POLICY_FAILURES)


def run_failed(terminations: Mapping[str, int] | None, episodes: int) -> bool:
    """Whether a run's policy failures exceed the allowed share (an empty run is failed)."""
    return bool(runs_failed(np.array([policy_failure_count(terminations)]), np.array([episodes]))[0])


def runs_failed(failures: np.ndarray, episodes: np.ndarray) -> np.ndarray:
    """:func:`run_failed` of many runs, from their policy failure counts and episodes."""
    failed: np.ndarray = (episodes <= 0) | (failures > POLICY_FAILURE_SHARE * episodes)
    return failed


def group_figures(episodes: Iterable[Mapping[str, Any]], setting: str) -> dict[str, Any]:
    """Per-group figures of one run, what a bootstrap needs: ``{"ids", "values", "pooled"}``.

    ``episodes`` are dicts with ``group`` and the episode's metrics and counters merged. ``values[key]``
    holds each group's metric (``None`` where unmeasured); ``pooled[key]`` each group's
    ``[numerator, denominator]`` of a pooled ratio.
    """
    rows = sorted(episodes, key=lambda e: int(e["group"]))
    values: dict[str, list[float | None]] = {}
    pooled: dict[str, list[list[float]]] = {}
    for m in metrics_for(setting):
        if m.key in POOLED:
            num, den = POOLED[m.key]
            pooled[m.key] = [[float(e.get(num) or 0), float(e.get(den) or 0)] for e in rows]
        else:
            values[m.key] = [_number(e.get(m.key)) for e in rows]
    return {"ids": [int(e["group"]) for e in rows], "values": values, "pooled": pooled}


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if np.isfinite(value) else None


def as_resampled(values: Any) -> np.ndarray:
    """Per-group figures as every resample reads them: float64 arrays of float32 values (NaN kept).

    A resample's figure is a sum of counts × figures. Held as float32 (24 significant bits), every term is
    exact in float64, and so is the sum of a board's 30 terms whose magnitudes lie within 2**19 of each other:
    the same resampled figure whatever the order of summation (one BLAS kernel or another, one machine or
    another), and a board keeps half the bytes. The
    rounding moves a figure by at most 6e-8 of itself, far below what any metric resolves."""
    rounded: np.ndarray = np.asarray(values, dtype=np.float64).astype(np.float32).astype(np.float64)
    return rounded


def resample_counts(groups: int, resamples: int = RESAMPLES, seed: int = SEED) -> np.ndarray:
    """How often each group is drawn in each resample: an int array (resamples, groups)."""
    rng = np.random.default_rng([seed, groups])
    return rng.multinomial(groups, np.full(groups, 1.0 / groups), size=resamples).astype(np.float64)


def timing_seed(values: Sequence[float | None] | np.ndarray) -> int:
    """The seed of an entry's timing noise: its per-group figures of the metric (None or NaN = unmeasured;
    as resamples read them, :func:`as_resampled`), as little-endian float64 bytes, hashed with :data:`SEED` (BLAKE2b, 64 bits)."""
    column = as_resampled(values).reshape(-1)
    canonical = np.where(np.isfinite(column), column, np.nan).astype("<f8")  # one NaN, whatever its origin
    key = SEED.to_bytes(8, "little")
    return int.from_bytes(hashlib.blake2b(canonical.tobytes(), digest_size=8, key=key).digest(), "little")


#: SplitMix64's multipliers (the increment and its two mixing steps), as the kernels take them.
SPLITMIX = (0x9E3779B97F4A7C15, 0xBF58476D1CE4E5B9, 0x94D049BB133111EB)
_GOLDEN, _MIX1, _MIX2 = (np.uint64(c) for c in SPLITMIX)


def timing_noise(seeds: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Uniform draws in [-1, 1): (entries, rows), entry ``i``'s for resamples ``rows`` of the plan.

    Counter based (SplitMix64 of the seed and the resample's index), so a subset of resamples costs only
    itself and equals those resamples of the whole: the board engine renormalises a few resamples at a time."""
    # In place on two arrays (each pass a temporary before): the same operations, so the same bits.
    with np.errstate(over="ignore"):  # unsigned arithmetic modulo 2**64 is the point
        z = np.add(
            np.asarray(seeds, dtype=np.uint64)[:, None],
            ((np.asarray(rows, dtype=np.uint64) + np.uint64(1)) * _GOLDEN)[None, :],
        )
        shifted = np.empty_like(z)
        for shift, mix in ((30, _MIX1), (27, _MIX2), (31, None)):
            z ^= np.right_shift(z, np.uint64(shift), out=shifted)
            if mix is not None:
                z *= mix
        z >>= np.uint64(11)
    # 2 × (z × 2**-53) − 1 as z × 2**-52 − 1: scaling by a power of two is exact, so the same bits
    signed: np.ndarray = np.multiply(z, 2.0**-52, out=shifted.view(np.float64))
    signed -= 1.0
    return signed


def metric_samples(figures: Sequence[Mapping[str, Any]], key: str, counts: np.ndarray) -> np.ndarray:
    """The run figure of ``key`` for each entry under each resample: (resamples, entries), NaN = unmeasured.

    Entries without figures for ``key`` are NaN throughout.
    """
    g = counts.shape[1]
    missing = [np.nan] * g
    if any(key in (f.get("pooled") or {}) for f in figures):
        empty = [[0.0, 0.0]] * g
        pairs = as_resampled([(f.get("pooled") or {}).get(key) or empty for f in figures])
        pairs = pairs.reshape(len(figures), g, 2)
        top, bottom = counts @ pairs[:, :, 0].T, counts @ pairs[:, :, 1].T
    else:
        # dtype=float turns None (unmeasured) into NaN in one C pass
        vals = as_resampled([(f.get("values") or {}).get(key) or missing for f in figures])
        vals = vals.reshape(len(figures), g)
        ok = np.isfinite(vals)
        top, bottom = counts @ np.where(ok, vals, 0.0).T, counts @ ok.T.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        top /= bottom
    top[bottom <= 0] = np.nan
    means: np.ndarray = top
    return means


def interval(
    samples: np.ndarray, confidence: float = CONFIDENCE, *, decimals: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Percentile interval along axis 0, ignoring NaN (NaN where every sample is NaN).

    Linear interpolation between order statistics, as ``numpy.nanquantile`` does, with one sort over all
    columns: on 1,000 resamples × 10,000 entries this took 0.28 s where ``nanquantile`` took 0.8 s (numpy 2.4).
    ``decimals``: the interval of the samples rounded so (``numpy.round``), computed by rounding only the
    order statistics it interpolates between — rounding is monotonic, so they are the rounded samples'.
    """
    tail = (1.0 - confidence) / 2.0
    ordered = np.sort(samples, axis=0)  # NaN sorts last
    finite = np.isfinite(samples).sum(axis=0)
    return (
        _order_stat(ordered, finite, tail, decimals),
        _order_stat(ordered, finite, 1.0 - tail, decimals),
    )


def _order_stat(ordered: np.ndarray, finite: np.ndarray, q: float, decimals: int | None) -> np.ndarray:
    position = q * np.maximum(finite - 1, 0)
    below = np.floor(position).astype(np.intp)
    above = np.minimum(below + 1, np.maximum(finite - 1, 0))
    low = np.take_along_axis(ordered, below[None, ...], axis=0)[0]
    high = np.take_along_axis(ordered, above[None, ...], axis=0)[0]
    if decimals is not None:
        low, high = np.round(low, decimals), np.round(high, decimals)
    value = low + (high - low) * (position - below)
    return np.where(finite > 0, value, np.nan)


def rank_samples(scores: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Competition ranks (1 + strictly better entries) of each row of a (resamples, entries) score array
    (``out``: an int32 array that shape to write them into).

    Where the kernels are built, a counting sort of each row (``_kernels.rank_rows``: a bucket per entry, a
    few values to sort in each); else, or where a score is not finite, :func:`_ranked_by_numpy`. Both give
    every entry of a run of ties the run's best rank, and the same ranks (``tests/scoring/test_kernels.py``)."""
    r, n = scores.shape
    out = np.empty((r, n), dtype=np.int32) if out is None else out
    if out.shape != (r, n) or out.dtype != np.int32 or not out.flags.c_contiguous:
        raise ValueError(f"ranks go into a C-contiguous int32 array of shape {(r, n)}")
    if n == 0:
        return out
    # float32 scores rank alike as float64 (the conversion is exact); a copy is a pass, the sort many
    if compiled is not None and compiled.rank_rows(np.ascontiguousarray(scores, np.float64), out, r, n):
        return out
    return _ranked_by_numpy(scores, out)


def _ranked_by_numpy(scores: np.ndarray, out: np.ndarray) -> np.ndarray:
    """:func:`rank_samples` by numpy's sorts: a block of rows at a time, each ranked by one sort of integer keys
    that carry their column (:func:`_ranked_by_keys`, its arrays made once and reused by every block: a new one
    per block was fresh pages for the kernel to zero); a block whose scores do not fit such keys, or whose keys
    tie scores that are not equal, by an argsort of its scores (:func:`_ranked_by_argsort`)."""
    r, n = scores.shape
    if n == 0:
        return out
    step = min(r, max(1, _RANKED_AT_ONCE // n))  # rows at a time: ≈ 30 bytes a score of transient arrays
    buffers = _KeyBuffers(
        np.empty((step, n)),
        np.empty((step, n), np.int64),
        np.empty((step, n), np.int64),
        np.tile(np.arange(1, n + 1, dtype=np.int32), step),
        np.arange(0, step * n, n, dtype=np.int64)[:, None],
    )
    for a in range(0, r, step):
        block, ranks = scores[a : a + step], out[a : a + step]
        if not _ranked_by_keys(block, ranks, buffers):
            _ranked_by_argsort(block, ranks)
    return out


#: Scores ranked at a time by :func:`rank_samples`: its transient arrays ≈ 26 MB (≈ 100 MB at 4 million, which
#: a board's full computation held on top of its workspace) and a few per cent faster, each pass over a block
#: of keys finding more of it in the cache (``bench/board_kernels.py``: 1,000 resamples × 10,000 entries
#: 0.35–0.37 → 0.32–0.35 CPU-s; 100 × 100,000 0.48 → 0.47).
_RANKED_AT_ONCE = 1_000_000


@dataclass(frozen=True, slots=True)
class _KeyBuffers:
    """The arrays :func:`_ranked_by_keys` works in (a block of rows × entries each), reused block after block."""

    scaled: np.ndarray  # float64
    keys: np.ndarray  # int64
    columns: np.ndarray  # int64
    positions: np.ndarray  # int32, flat: 1 … entries, once per row
    starts: np.ndarray  # int64, (rows, 1): where each row starts in a flat block


#: Key units per score unit in :func:`_ranked_by_keys`: a board's relative scores are read to 12 decimals
#: (``scores.EQUAL_DECIMALS``), so two that differ differ by a key unit or more.
_KEY_SCALE = 1e12


def _ranked_by_keys(block: np.ndarray, out: np.ndarray, buffers: _KeyBuffers) -> bool:
    """Rank ``block``'s rows into ``out`` by sorting integer keys, if it can be done exactly; False if not.

    An entry's key is its distance below the block's best score in :data:`_KEY_SCALE` units, truncated, with
    its column in the low bits: one sort of plain integers orders a row best first and says where each entry
    was (a value sort of 64-bit integers is about twice as fast as an argsort of the scores, and the argsort's
    gather and run-end passes go too; at 1,000 resamples × 10,000 entries 0.49 → 0.27 CPU-s). The key falls as
    the score rises (every step is monotonic), so a lower key is a strictly better score; equal scores have
    equal keys, and keys that tie scores which differ (none, for scores read to 12 decimals) send the block
    back to the argsort. An entry's rank is then 1 + its position, or 1 + the first position of its run of
    equal keys."""
    r, n = block.shape
    bits = max(1, (n - 1).bit_length())
    best, worst = np.max(block), np.min(block)  # NaN propagates: such a block is argsorted
    if not (np.isfinite(best) and np.isfinite(worst)):
        return False
    with np.errstate(over="ignore"):  # a span past the largest double is too wide, as any above the keys'
        span = (best - worst) * _KEY_SCALE
    if span >= 2.0 ** min(52, 62 - bits):
        return False
    scaled = np.subtract(best, block, out=buffers.scaled[:r])
    scaled *= _KEY_SCALE
    scaled += 0.5  # a score read to 12 decimals lands mid-unit: its key does not hang on rounding noise
    keys = buffers.keys[:r]
    np.copyto(keys, scaled, casting="unsafe")  # truncated, as ``astype`` does
    keys <<= bits
    keys |= np.arange(n, dtype=np.int64)
    keys.sort(axis=1)
    columns = np.bitwise_and(keys, (1 << bits) - 1, out=buffers.columns[:r])
    keys >>= bits
    tied = keys[:, 1:] == keys[:, :-1]
    rows, at = np.nonzero(tied) if tied.any() else (np.zeros(0, np.intp), np.zeros(0, np.intp))
    if rows.size and not np.array_equal(block[rows, columns[rows, at]], block[rows, columns[rows, at + 1]]):
        return False
    # each entry's position, scattered to its place in the (contiguous) block by one flat index: twice as fast
    # as ``put_along_axis``, which builds an index per axis
    columns += buffers.starts[:r]
    flat = out.reshape(-1)
    flat[columns.reshape(-1)] = buffers.positions[: r * n]
    if rows.size:  # an entry that ties the one before it takes its run's first position (runs are short)
        later = rows * n + at + 1  # ascending
        starts = np.ones(len(later), dtype=bool)
        starts[1:] = later[1:] != later[:-1] + 1  # (a row's last and the next row's first are ≥ 2 apart)
        first = np.where(starts, later - 1, 0)
        np.maximum.accumulate(first, out=first)
        flat[columns[rows, at + 1]] = first - rows * n + 1
    return True


def _ranked_by_argsort(block: np.ndarray, out: np.ndarray) -> None:
    """Rank ``block``'s rows into ``out``: an argsort of each row; an entry's rank is read off the end of its
    run of equal scores (every entry of a run of ties shares it), then put back in entry order. (A NaN, which
    a board's relative scores never hold, sorts last, so counts as better than every score.)"""
    n = block.shape[1]
    order = np.argsort(block, axis=1)
    ascending = np.take_along_axis(block, order, axis=1)
    # the last position of each run of equal scores, carried back over the run
    last = np.full(block.shape, n - 1, dtype=np.int32)
    ends = ascending[:, 1:] != ascending[:, :-1]
    last[:, :-1] = np.where(ends, np.arange(n - 1, dtype=np.int32), n - 1)
    last = np.minimum.accumulate(last[:, ::-1], axis=1)[:, ::-1]
    # strictly better: the n - 1 - last above its run
    np.put_along_axis(out, order, n - last, axis=1)


def rank_interval(
    ranks: np.ndarray, confidence: float = CONFIDENCE, *, overwrite_input: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Integer rank interval per entry: the ranks it takes in the central ``confidence`` of resamples
    (``numpy.quantile``'s ``lower`` and ``higher`` order statistics), read off each entry's sorted ranks: numpy's
    vectorised sort takes half the time of a partition at the two positions (1,000 × 10,000: 0.06 against 0.12
    CPU-s; selecting them in compiled code, each entry's ranks gathered from its column, saved a seventh).
    ``overwrite_input``: sort ``ranks`` in place (each column's ranks come out sorted), not a copy."""
    tail = (1.0 - confidence) / 2.0
    r = ranks.shape[0]
    if r == 0:
        raise ValueError("a rank interval needs resamples")
    low = int(np.floor(tail * (r - 1)))
    high = int(np.ceil((1.0 - tail) * (r - 1)))
    if overwrite_input:
        ranks.sort(axis=0)
        picked = ranks
    else:
        picked = np.sort(ranks, axis=0)
    return picked[low].astype(int), picked[high].astype(int)


def order_statistics(values: np.ndarray, positions: Sequence[int]) -> np.ndarray:
    """The values a sort of each row of ``values`` (rows, n; float64) puts at ``positions`` (ascending):
    (rows, positions). By selection where the kernels are built (``_kernels.order_statistics``: a third of the
    time of a sort of 1,000 samples), else by numpy's sort; NaN sorts last either way."""
    rows, n = values.shape
    at = np.asarray(positions, dtype=np.int64).reshape(-1)
    if len(at) and (at[0] < 0 or at[-1] >= n or np.any(np.diff(at) < 0)):
        raise ValueError(f"positions must be ascending, each in [0, {n})")
    out = np.empty((rows, len(at)))
    if rows == 0 or len(at) == 0:
        return out
    contiguous = np.ascontiguousarray(values, dtype=np.float64)
    if compiled is not None and compiled.order_statistics(contiguous, n, at, out):
        return out
    return np.sort(values, axis=1)[:, at]


def groups_needed(
    sd_difference: float, difference: float, *, z_alpha: float = 1.96, z_power: float = 0.84
) -> int:
    """Groups a paired comparison needs to find ``difference`` with 80 % power at the 5 % level.

    ``sd_difference`` is the standard deviation of the per-group differences (normal approximation).
    """
    if difference <= 0:
        raise ValueError("difference must be positive")
    return max(2, int(np.ceil(((z_alpha + z_power) * sd_difference / difference) ** 2)))


def paired_difference(
    a: Mapping[str, Any], b: Mapping[str, Any], key: str, resamples: int = RESAMPLES, seed: int = SEED
) -> dict[str, Any]:
    """A − B on ``key`` over their common groups: point difference and bootstrap interval."""
    common = sorted(set(a["ids"]) & set(b["ids"]))
    if not common:
        raise ValueError("the two runs share no group")
    pa, pb = _select(a, common), _select(b, common)
    counts = resample_counts(len(common), resamples, seed)
    full = np.ones((1, len(common)))
    both = metric_samples([pa, pb], key, np.vstack([full, counts]))
    diff = both[:, 0] - both[:, 1]
    lo, hi = interval(diff[1:, None])
    point = float(diff[0])
    return {
        "difference": None if np.isnan(point) else point,
        "low": _opt(lo[0]),
        "high": _opt(hi[0]),
        "groups": len(common),
    }


def _select(figures: Mapping[str, Any], ids: Sequence[int]) -> dict[str, Any]:
    where = {g: i for i, g in enumerate(figures["ids"])}
    pick = [where[g] for g in ids]
    return {
        "ids": list(ids),
        "values": {k: [v[i] for i in pick] for k, v in (figures.get("values") or {}).items()},
        "pooled": {k: [v[i] for i in pick] for k, v in (figures.get("pooled") or {}).items()},
    }


def _opt(value: float) -> float | None:
    return None if np.isnan(value) else float(value)
