"""Group sampling: deterministic per seed and group, and each dataset's rule (docs/benchmark.md, "Datasets")."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from robobpp.datasets import (
    DATASETS,
    UnknownDatasetError,
    UnknownSplitError,
    episode_specs,
    group_seed,
    load_pool,
)
from robobpp.datasets.pool import Pool
from robobpp.datasets.sampling import sample_indices


def _toy_pool(n: int, weights: np.ndarray | None = None) -> Pool:
    dims = np.column_stack([np.arange(1, n + 1, dtype=float), np.ones(n), np.ones(n)])
    return Pool("toy", "train", dims, np.ones(n), weights, np.arange(n), n)


# ---- offline: the rules on hand-made pools ----------------------------------------------------------


def test_consecutive_windows_are_contiguous_and_cover_the_ends() -> None:
    pool = _toy_pool(100)
    starts = set()
    for seed in range(400):
        idx = sample_indices(pool, "consecutive", np.random.default_rng(seed), 80)
        assert np.array_equal(idx, np.arange(idx[0], idx[0] + 80))
        starts.add(int(idx[0]))
    assert starts == set(range(21))  # every start 0..n-80 is possible, nothing past the end


def test_consecutive_needs_a_pool_at_least_one_group_long() -> None:
    with pytest.raises(ValueError, match="fewer than a group"):
        sample_indices(_toy_pool(50), "consecutive", np.random.default_rng(0), 80)


def test_weighted_draws_follow_the_weights() -> None:
    weights = np.array([0.5, 0.3, 0.15, 0.05, 0.0])
    pool = _toy_pool(5, weights)
    draws = np.concatenate(
        [sample_indices(pool, "weighted", np.random.default_rng(s), 80) for s in range(250)]
    )
    counts = np.bincount(draws, minlength=5)
    expected = weights * len(draws)
    assert counts[4] == 0  # a zero-weight entry is never drawn
    sigma = np.sqrt(expected * (1 - weights))
    assert np.all(np.abs(counts[:4] - expected[:4]) < 5 * sigma[:4])


def test_group_seed_depends_on_every_part() -> None:
    base = group_seed("repetitive", "train", 0, 0)
    others = {
        group_seed("diverse", "train", 0, 0),
        group_seed("repetitive", "test", 0, 0),
        group_seed("repetitive", "train", 1, 0),
        group_seed("repetitive", "train", 0, 1),
    }
    assert base not in others and len(others) == 4
    assert base == group_seed("repetitive", "train", 0, 0)
    assert 0 <= base < 2**63


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"dataset": "nope"}, UnknownDatasetError),
        ({"dataset": "diverse", "split": "validation"}, UnknownSplitError),
        ({"dataset": "diverse", "seed": -1}, ValueError),
        ({"dataset": "diverse", "groups": -2}, ValueError),
        ({"dataset": "diverse", "group_size": 0}, ValueError),
    ],
)
def test_bad_arguments_are_refused_before_any_data_is_touched(kwargs: dict, error: type) -> None:
    with pytest.raises(error):
        episode_specs(**kwargs)


# ---- real data ---------------------------------------------------------------------------------------


@pytest.mark.network
@pytest.mark.parametrize("dataset", list(DATASETS))
def test_specs_are_deterministic_and_group_independent(real_data: Path, dataset: str) -> None:
    a = episode_specs(dataset, "train", groups=4, seed=11)
    b = episode_specs(dataset, "train", groups=4, seed=11)
    assert a == b
    assert episode_specs(dataset, "train", groups=9, seed=11)[:4] == a  # group i ignores `groups`
    assert episode_specs(dataset, "train", groups=4, seed=12) != a
    registry = DATASETS[dataset]
    for i, spec in enumerate(a):
        assert (spec.dataset, spec.split, spec.group) == (dataset, "train", i)
        assert len(spec.boxes) == 80
        assert spec.container == registry.container
        assert spec.collapse_threshold_cm == registry.collapse_threshold_cm
        assert spec.seed == group_seed(dataset, "train", 11, i)
    assert len({s.seed for s in a}) == 4


@pytest.mark.network
def test_repetitive_groups_are_consecutive_windows_of_the_time_ordered_pool(real_data: Path) -> None:
    pool = load_pool("repetitive", "test")
    table = np.column_stack([pool.dims, pool.masses])
    for spec in episode_specs("repetitive", "test", groups=5, seed=3):
        group = np.array([[b.length, b.width, b.height, b.mass] for b in spec.boxes])
        idx = sample_indices(pool, "consecutive", np.random.default_rng(spec.seed), 80)
        np.testing.assert_array_equal(group, table[idx])
        assert np.all(np.diff(idx) == 1)
        # Runs of identical boxes from pick quantities survive inside the window.
        same = np.all(group[1:] == group[:-1], axis=1)
        assert same.any()


@pytest.mark.network
def test_diverse_groups_follow_shipment_proportions(real_data: Path) -> None:
    pool = load_pool("diverse", "train")
    assert pool.weights is not None
    specs = episode_specs("diverse", "train", groups=250, seed=5)
    index = {tuple(d): i for i, d in enumerate(pool.dims.tolist())}  # dims may repeat across SKUs
    drawn = np.zeros(len(pool))
    for spec in specs:
        for b in spec.boxes:
            drawn[index[(b.length, b.width, b.height)]] += 1
    # Aggregate weights by distinct size (several SKUs can share one).
    weight = np.zeros(len(pool))
    for i, d in enumerate(pool.dims.tolist()):
        weight[index[tuple(d)]] += pool.weights[i]
    n = drawn.sum()
    top = np.argsort(weight)[-15:]
    expected = weight[top] * n
    sigma = np.sqrt(expected * (1 - weight[top]))
    assert np.all(np.abs(drawn[top] - expected) < 5 * sigma)
    # Far from uniform: the 15 most shipped sizes take a much larger share than 15/len(pool).
    assert drawn[top].sum() / n > 5 * 15 / len(pool)


@pytest.mark.network
def test_longboard_groups_are_uniform_draws(real_data: Path) -> None:
    pool = load_pool("longboard", "test")
    draws = np.concatenate(
        [
            sample_indices(pool, "uniform", np.random.default_rng(group_seed("longboard", "test", 0, g)), 80)
            for g in range(300)
        ]
    )
    counts = np.bincount(draws, minlength=len(pool))
    expected = len(draws) / len(pool)
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert chi2 < 2 * (len(pool) - 1)  # df = 56; a 2x margin is far in the tail of chi2(56)
    assert counts.min() > 0
    boxes = {
        (b.length, b.width, b.height) for s in episode_specs("longboard", "test", groups=30) for b in s.boxes
    }
    assert boxes and not any(length > 250 for length, _, _ in boxes)  # unplaceable panels are never drawn


@pytest.mark.network
def test_masses_follow_the_registry(real_data: Path) -> None:
    spec = episode_specs("longboard", "train", groups=1)[0]
    for b in spec.boxes:
        assert b.mass == pytest.approx(b.length * b.width * b.height * 1e-6 * 400.0)
    heavier = episode_specs("diverse", "train", groups=1, density_kg_m3=500.0)[0]
    normal = episode_specs("diverse", "train", groups=1)[0]
    assert [b.mass for b in heavier.boxes] == pytest.approx([2 * b.mass for b in normal.boxes])
