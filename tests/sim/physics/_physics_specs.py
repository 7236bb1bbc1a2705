"""Episode specs built by hand for the physics tests (offline, no dataset import)."""

from __future__ import annotations

import random

from robobpp.core import Box, ContainerSpec, EpisodeSpec
from robobpp.datasets import get_dataset


def spec_of(
    boxes: list[Box], dataset: str = "repetitive", threshold: float | None = None, group: int = 0
) -> EpisodeSpec:
    """An episode over ``boxes`` in the dataset's container with its collapse threshold (or ``threshold``)."""
    ds = get_dataset(dataset)
    limit = ds.collapse_threshold_cm if threshold is None else threshold
    return EpisodeSpec(dataset, "train", group, tuple(boxes), ds.container, limit, seed=group)


def repetitive_like(group: int, n: int = 80, container: ContainerSpec | None = None) -> EpisodeSpec:
    """Runs of identical boxes (a few types per group), like the repetitive dataset's pick records."""
    rng = random.Random(1000 + group)
    types = [Box(rng.randint(15, 35), rng.randint(15, 30), rng.randint(10, 25), round(rng.uniform(1, 8), 2))
             for _ in range(3)]  # fmt: skip
    boxes: list[Box] = []
    while len(boxes) < n:
        boxes += [rng.choice(types)] * rng.randint(1, 6)
    ds = get_dataset("repetitive")
    threshold = (4.0, 7.0)[group % 2]
    return EpisodeSpec(
        "synthetic", "train", group, tuple(boxes[:n]), container or ds.container, threshold, group
    )
