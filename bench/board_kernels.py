"""Kernels of a board's full computation in isolation: ranking every resample (``stats.rank_samples``: compiled,
and numpy's keys at several block sizes), a chunk of entries' order statistics (compiled selection against
numpy's sort), the timing noise (``stats.timing_noise``; ``scores.add_timing_noise`` compiled and numpy's), a
tile's relative and stable normalisation (``scores.min_max``, ``scores.add_weighted_min_max`` compiled and numpy's,
``scores.anchored``), a tile's bounds (``matrix._fold``, compiled and numpy's), and a board's stored parts decoded and kept by its part table, many
at a time (``entries.StoredParts``, what the start does) against one by one (``EntryPart.decode``). Scores are
drawn like a board's relative scores (an entry's level plus resample noise, read to 12 decimals); parts are
execution runs of 30 groups. Best of three, CPU seconds.

    OPENBLAS_NUM_THREADS=1 python bench/board_kernels.py [--entries 10000] [--resamples 1000]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from unittest import mock

import numpy as np

from robobpp.boards import matrix
from robobpp.scoring import kernels, stats
from robobpp.scoring import scores as scores_module
from robobpp.scoring.entries import EntryPart, PartTable, StoredParts, entry_part
from robobpp.scoring.scores import ANCHORS, add_timing_noise, add_weighted_min_max, anchored, min_max


def best_cpu_s(work: Callable[[], object], runs: int = 3) -> float:
    best = float("inf")
    for _ in range(runs):
        started = time.process_time()
        work()
        best = min(best, time.process_time() - started)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--entries", type=int, default=10_000)
    parser.add_argument("--resamples", type=int, default=1_000)
    args = parser.parse_args()
    rng = np.random.default_rng(1)
    n, r = args.entries, args.resamples
    scores = np.round(rng.random(n)[None, :] * 0.6 + rng.random((r, n)) * 0.05, 12)
    out = np.empty(scores.shape, np.int32)
    if kernels.BUILT:
        seconds = best_cpu_s(lambda: stats.rank_samples(scores, out=out))
        print(
            f"rank_samples, {r:,} x {n:,}, compiled (a counting sort of each resample): {seconds:.3f} CPU-s"
        )
    default = stats._RANKED_AT_ONCE
    for at_once in (4_000_000, 1_000_000, 400_000):
        stats._RANKED_AT_ONCE = at_once
        seconds = best_cpu_s(lambda: stats._ranked_by_numpy(scores, out))
        mark = " (the default)" if at_once == default else ""
        print(f"rank_samples, {r:,} x {n:,}, numpy's keys, {at_once:,} at a time{mark}: {seconds:.3f} CPU-s")
    stats._RANKED_AT_ONCE = default
    samples = np.ascontiguousarray(
        scores[:, :512].T
    )  # a chunk of 512 entries' samples, as a board scores them
    at = [24, 25, r - 26, r - 25] if r >= 51 else [0, r - 1]
    chunks = 20
    if kernels.BUILT:
        seconds = best_cpu_s(lambda: [stats.order_statistics(samples, at) for _ in range(chunks)])
        print(f"order statistics, {chunks} chunks of 512 x {r:,}, compiled (selection): {seconds:.3f} CPU-s")
    seconds = best_cpu_s(lambda: [np.sort(samples, axis=1)[:, at] for _ in range(chunks)])
    print(f"order statistics, {chunks} chunks of 512 x {r:,}, numpy's sort: {seconds:.3f} CPU-s")
    seeds = rng.integers(0, 2**64, size=3_000, dtype=np.uint64)
    seconds = best_cpu_s(lambda: stats.timing_noise(seeds, np.arange(1_000)))
    print(f"timing_noise (numpy's draws alone), 3,000 entries x 1,000 resamples: {seconds:.3f} CPU-s")
    times = rng.random((1_200, 133))
    drawn: list[int | None] = [int(s) for s in seeds[:1_200]]

    def noise_tiles() -> None:
        for _ in range(100):
            add_timing_noise(times, drawn, np.arange(133))

    if kernels.BUILT:
        print(f"add_timing_noise, 100 tiles of 1,200 x 133, compiled: {best_cpu_s(noise_tiles):.3f} CPU-s")
    with mock.patch.object(scores_module, "compiled", None):
        print(f"add_timing_noise, 100 tiles of 1,200 x 133, numpy: {best_cpu_s(noise_tiles):.3f} CPU-s")
    tile = rng.random((1_200, 133))  # a tile of a full computation at 10,000 entries
    lo, hi = tile.min(axis=0), tile.max(axis=0)
    seconds = best_cpu_s(lambda: [min_max(tile, lo, hi, "occupancy") for _ in range(100)])
    print(f"min_max, 100 tiles of 1,200 x 133: {seconds:.3f} CPU-s")
    total = np.zeros_like(tile)

    def weighted_tiles() -> None:
        for _ in range(100):
            add_weighted_min_max(total, tile, lo, hi, "decision_time", 0.1, finish=True)

    if kernels.BUILT:
        print(
            f"add_weighted_min_max, 100 tiles of 1,200 x 133, compiled: {best_cpu_s(weighted_tiles):.3f} CPU-s"
        )
    with mock.patch.object(scores_module, "compiled", None):
        print(
            f"add_weighted_min_max, 100 tiles of 1,200 x 133, numpy: {best_cpu_s(weighted_tiles):.3f} CPU-s"
        )
    part = rng.random((8, 1_200, 133))  # every metric's samples of a tile
    low, high = np.full((2, 8, 133), np.nan)

    def fold_tiles() -> None:
        for _ in range(100):
            matrix._fold(low, high, part)

    if kernels.BUILT:
        print(f"bounds folded, 100 tiles of 8 x 1,200 x 133, compiled: {best_cpu_s(fold_tiles):.3f} CPU-s")
    with mock.patch.object(matrix, "compiled", None):
        print(f"bounds folded, 100 tiles of 8 x 1,200 x 133, numpy: {best_cpu_s(fold_tiles):.3f} CPU-s")
    for key in ("occupancy", "decision_time"):

        def anchor_tiles(key: str = key) -> None:
            for _ in range(100):
                anchored(tile, key)

        print(f"anchored ({ANCHORS[key][2]}), 100 tiles of 1,200 x 133: {best_cpu_s(anchor_tiles):.3f} CPU-s")
    stored = [_part(rng).encode() for _ in range(min(n, 10_000))]
    sids = list(range(1, len(stored) + 1))
    many = best_cpu_s(
        lambda: PartTable("execution").put_many(StoredParts.decode("execution", sids, stored)[0])
    )
    alone = best_cpu_s(
        lambda: PartTable("execution").put_many(
            {sid: EntryPart.decode(data, "execution") for sid, data in zip(sids, stored, strict=True)}
        )
    )
    print(f"{len(stored):,} stored parts decoded and kept: {many:.3f} CPU-s at once, {alone:.3f} one by one")


def _part(rng: np.random.Generator, groups: int = 30) -> EntryPart:
    keys = ("space_utilization", "occupancy", "decision_time", "local_stability", "static_stability")
    values = {key: rng.random(groups).tolist() for key in (*keys, "trajectory_length")}
    pooled = {
        key: [[float(rng.integers(0, 5)), float(rng.integers(1, 40))] for _ in range(groups)]
        for key in ("collapsed_placement", "dangerous_operation")
    }
    return entry_part({"ids": list(range(groups)), "values": values, "pooled": pooled}, "execution")


if __name__ == "__main__":
    main()
