"""The lookup attack (robobpp.datasets.lookup) and what it learns from the public data about the private groups
(docs/datasets.md, "Private groups nobody can look up")."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from robobpp.core import Box
from robobpp.datasets import DATASETS, EVAL_GROUPS, build_private, group_seed, load_pool, load_private
from robobpp.datasets.lookup import PublicIndex, public_index
from robobpp.datasets.private import HOLDOUT_DIR, PRIVATE_SPLIT
from robobpp.datasets.sampling import sample_indices


def _boxes(sizes: list[int]) -> np.ndarray:
    return np.array([[s, 1.0, 1.0, 1.0] for s in sizes])


# ---- offline: the attack on hand-made sequences ----------------------------------------------------------


def test_a_window_is_told_once_its_prefix_is_unique() -> None:
    index = PublicIndex([_boxes([1, 2, 3, 1, 2, 4, 5, 6, 7]), _boxes([9, 8])])
    # [1, 2] occurs twice (continuing 3… and 4…), [1, 2, 4] once: the rest is told after three boxes.
    found = index.lookup(_boxes([1, 2, 4, 5, 6]))
    assert (found.told_after, found.matched_prefix, found.boxes) == (3, 3, 5)
    # A unique first box tells the rest at once; Box objects read as the policy sees them.
    assert index.lookup([Box(5, 1, 1, 1), Box(6, 1, 1, 1), Box(7, 1, 1, 1)]).told_after == 1


def test_a_group_that_leaves_every_public_run_is_not_told() -> None:
    index = PublicIndex([_boxes([1, 2, 3, 1, 2, 4, 5, 6, 7]), _boxes([9, 8])])
    shuffled = index.lookup(_boxes([5, 6, 1, 2, 3]))  # starts as a run, then goes its own way
    assert shuffled.told_after is None and shuffled.matched_prefix == 2
    # All matches agree but the group differs: the attacker is wrong, not told.
    assert index.lookup(_boxes([9, 7])).told_after is None
    # A run cut by the end of its sequence tells nothing past it (the next sequence is not its continuation).
    assert index.lookup(_boxes([6, 7, 9])).told_after is None
    unknown = index.lookup(_boxes([42, 1, 2]))
    assert (unknown.told_after, unknown.matched_prefix) == (None, 0)


def test_an_index_needs_a_sequence() -> None:
    with pytest.raises(ValueError, match="no public sequence"):
        PublicIndex([])


# ---- real data: the server's draws ----------------------------------------------------------------------


def _v1_tables(dataset: str, seed: int) -> list[np.ndarray]:
    """The groups sampler version 1 drew with this seed (every split with the registry's ``sampling``)."""
    pool = load_pool(dataset, PRIVATE_SPLIT)
    out = []
    for g in range(EVAL_GROUPS):
        rng = np.random.default_rng(group_seed(dataset, PRIVATE_SPLIT, seed, g))
        idx = sample_indices(pool, DATASETS[dataset].sampling, rng, 80)
        out.append(np.column_stack([pool.dims[idx], pool.masses[idx]]))
    return out


@pytest.mark.network
def test_the_public_data_tells_the_rest_of_no_private_or_holdout_group(
    real_data: Path, tmp_path: Path
) -> None:
    """As ``robobpp serve`` builds them (server/bootstrap.py): the private split and its hold-out draw beside it,
    each with its own seed, every dataset; the attack searches every public pool, train and test."""
    index = public_index()
    root = tmp_path / "datasets_private"
    seeds = {root: 20261127, root / HOLDOUT_DIR: 77}
    told_v1 = 0
    for where, seed in seeds.items():
        build_private(where, seed=seed)
        for dataset in DATASETS:
            for spec in load_private(dataset, where):
                found = index.lookup(spec.boxes)
                assert found.told_after is None, (where.name, dataset, spec.group, found)
            # The attack is not blind: the same seeds under sampler version 1 are told.
            told_v1 += sum(index.lookup(t).told_after is not None for t in _v1_tables(dataset, seed))
    assert told_v1 >= 2 * EVAL_GROUPS * 3 // 4  # Repetitive, both draws: 58 of 60 at these seeds


@pytest.mark.network
def test_no_private_group_is_a_public_track_group(real_data: Path, tmp_path: Path) -> None:
    """The public track plays the train split's groups of seed 0 (worker/specs.py); a private group is none of
    them (their pools hold other records)."""
    from robobpp.datasets import episode_specs

    build_private(tmp_path, seed=5)
    for dataset in DATASETS:
        public = {s.boxes for s in episode_specs(dataset, "train", groups=EVAL_GROUPS, seed=0)}
        assert not public & {s.boxes for s in load_private(dataset, tmp_path)}
