"""Two kernels of a board's full computation in isolation: ranking every resample (``stats.rank_samples``) at
several block sizes, and the timing noise (``stats.timing_noise``). Scores are drawn like a board's relative
scores (an entry's level plus resample noise, read to 12 decimals). Best of three, CPU seconds.

    OPENBLAS_NUM_THREADS=1 python bench/board_kernels.py [--entries 10000] [--resamples 1000]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from robobpp.scoring import stats


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
    default = stats._RANKED_AT_ONCE
    for at_once in (4_000_000, 1_000_000, 400_000):
        stats._RANKED_AT_ONCE = at_once
        seconds = best_cpu_s(lambda: stats.rank_samples(scores, out=out))
        mark = " (the default)" if at_once == default else ""
        print(f"rank_samples, {r:,} x {n:,}, {at_once:,} at a time{mark}: {seconds:.3f} CPU-s")
    stats._RANKED_AT_ONCE = default
    seeds = rng.integers(0, 2**64, size=3_000, dtype=np.uint64)
    seconds = best_cpu_s(lambda: stats.timing_noise(seeds, np.arange(1_000)))
    print(f"timing_noise, 3,000 entries x 1,000 resamples: {seconds:.3f} CPU-s")


if __name__ == "__main__":
    main()
