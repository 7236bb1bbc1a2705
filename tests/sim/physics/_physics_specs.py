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


def _mm_box(rng: random.Random) -> Box:
    length, width, height = (round(rng.uniform(lo, hi), 1) for lo, hi in ((15, 35), (15, 30), (10, 25)))
    return Box(length, width, height, round(rng.uniform(1, 8), 2))


def repetitive_like(
    group: int, n: int = 80, container: ContainerSpec | None = None, millimetres: bool = False
) -> EpisodeSpec:
    """Runs of identical boxes (a few types per group), like the repetitive dataset's pick records.

    ``millimetres``: sides to 1 mm (27.4 cm) as in the real data, instead of whole centimetres. A policy
    on the 1 cm grid then puts neighbours a few millimetres into each other's footprint (within the edge
    tolerance), which pushes them apart and makes the full simulation's resting pile creep: the case
    where fast and full mode can part.
    """
    rng = random.Random(1000 + group)
    if millimetres:
        types = [_mm_box(rng) for _ in range(3)]
    else:
        types = [
            Box(rng.randint(15, 35), rng.randint(15, 30), rng.randint(10, 25), round(rng.uniform(1, 8), 2))
            for _ in range(3)
        ]
    boxes: list[Box] = []
    while len(boxes) < n:
        boxes += [rng.choice(types)] * rng.randint(1, 6)
    ds = get_dataset("repetitive")
    threshold = (4.0, 7.0)[group % 2]
    return EpisodeSpec(
        "synthetic", "train", group, tuple(boxes[:n]), container or ds.container, threshold, group
    )
