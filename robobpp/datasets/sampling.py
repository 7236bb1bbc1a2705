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
#: Version 2: the test split of ``repetitive`` (the private pool's) is drawn with ``palette``, no longer as a
#: window of the public test pool; every other (dataset, split) draws the same boxes as version 1.
SAMPLER_VERSION = "2"


def group_seed(dataset: str, split: str, seed: int, group: int) -> int:
    """The 63-bit seed of one group (stable across numpy versions: SeedSequence's hash is specified)."""
    sequence = np.random.SeedSequence(
        entropy=seed, spawn_key=(zlib.crc32(dataset.encode()), zlib.crc32(split.encode()), group)
    )
    return int(sequence.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def runs(pool: Pool) -> tuple[np.ndarray, np.ndarray]:
    """Start and length of each maximal run of identical boxes (size and mass) in pool order."""
    table = np.column_stack([pool.dims, pool.masses])
    starts = np.flatnonzero(np.r_[True, np.any(table[1:] != table[:-1], axis=1)])
    return starts, np.diff(np.r_[starts, len(pool)])


def _window_start(pool: Pool, rng: np.random.Generator, group_size: int) -> int:
    n = len(pool)
    if n < group_size:
        raise ValueError(f"{pool.dataset}/{pool.split} has {n} boxes, fewer than a group of {group_size}")
    return int(rng.integers(0, n - group_size + 1))


def _inverse_cdf(weights: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """Draws from ``weights`` by inverse CDF of uniforms: independent of how numpy implements choice()."""
    cdf = np.cumsum(weights)
    drawn: np.ndarray = np.minimum(np.searchsorted(cdf, uniforms * cdf[-1], side="right"), len(weights) - 1)
    return drawn


def _palette(pool: Pool, rng: np.random.Generator, group_size: int) -> np.ndarray:
    """Runs of the pool drawn with replacement from a palette of runs drawn with replacement from the pool.

    The palette holds as many runs as a window of ``group_size`` consecutive boxes at a uniform start covers
    (only that count is taken from the window, not its boxes), so a group repeats as few sizes as the time
    series does locally. Runs keep their lengths, and a group ends inside its last run. A run of length L
    enters the palette with probability ∝ L / shown(L), where shown(L) is the boxes of it a group holds on
    average over the ``group_size`` places u it can start at (mean of min(L, group_size − u)), so a box of a
    long run is about as likely to be drawn as a box of a short one (without the weight, the sizes of the test
    pool's three runs of 112–145 boxes, 6 % of its boxes, came out at half their share; with it, 0.74–0.82).
    Nothing ties the order to the pool's: no stretch of the public sequence tells what follows
    (docs/datasets.md, "Private groups nobody can look up").
    """
    starts, lengths = runs(pool)
    start = _window_start(pool, rng, group_size)
    first, last = np.searchsorted(starts, [start, start + group_size - 1], side="right") - 1
    cut = np.minimum(lengths, group_size)
    shown = (cut * (cut + 1) / 2 + cut * (group_size - cut)) / group_size
    palette = _inverse_cdf(lengths / shown, rng.random(int(last - first + 1)))
    parts, total = [], 0
    while total < group_size:
        run = int(palette[rng.integers(0, len(palette))])
        take = min(int(lengths[run]), group_size - total)
        parts.append(np.arange(starts[run], starts[run] + take))
        total += take
    return np.concatenate(parts)


def sample_indices(pool: Pool, sampling: str, rng: np.random.Generator, group_size: int) -> np.ndarray:
    """Pool indices of one group under a sampling rule (docs/benchmark.md, "Datasets")."""
    n = len(pool)
    if sampling == "consecutive":
        start = _window_start(pool, rng, group_size)
        return np.arange(start, start + group_size)
    if sampling == "palette":
        return _palette(pool, rng, group_size)
    if sampling == "weighted":
        assert pool.weights is not None
        return _inverse_cdf(pool.weights, rng.random(group_size))
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
    _check_int("groups", groups, 0)
    draw = GroupDraw(dataset, split, seed, group_size, density_kg_m3=density_kg_m3)
    return [draw(group) for group in range(groups)]


class GroupDraw:
    """Any group of a split, drawn on demand: group ``g`` is the same sequence :func:`episode_specs` gives as its
    ``g``-th, without drawing the groups before it (a Gym env draws a fresh group per reset this way)."""

    def __init__(
        self,
        dataset: str,
        split: str = "train",
        seed: int = 0,
        group_size: int = GROUP_SIZE,
        *,
        density_kg_m3: float | None = None,
    ) -> None:
        self.spec = check_split(dataset, split)
        _check_int("seed", seed, 0)
        _check_int("group_size", group_size, 1)
        self.dataset, self.split, self.seed, self.group_size = dataset, split, int(seed), group_size
        self.pool = load_pool(dataset, split, density_kg_m3=density_kg_m3)

    def __call__(self, group: int) -> EpisodeSpec:
        _check_int("group", group, 0)
        gseed = group_seed(self.dataset, self.split, self.seed, group)
        rng = np.random.default_rng(gseed)
        indices = sample_indices(self.pool, self.spec.sampling_of(self.split), rng, self.group_size)
        return EpisodeSpec(
            self.dataset,
            self.split,
            group,
            self.pool.boxes(indices),
            self.spec.container,
            self.spec.collapse_threshold_cm,
            gseed,
            SAMPLER_VERSION,
        )
