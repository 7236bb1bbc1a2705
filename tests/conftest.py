"""Shared fixtures: small hand-built episode specs that need no downloaded data."""

from __future__ import annotations

import numpy as np
import pytest

from robobpp.core import Box, ContainerSpec, EpisodeSpec


def make_spec(
    boxes: list[tuple[float, float, float]] | list[Box],
    container: tuple[float, float, float] = (10, 10, 10),
    threshold: float = 7.0,
    dataset: str = "handmade",
    group: int = 0,
) -> EpisodeSpec:
    """An episode over the given boxes (tuples are (l, w, h) with 1 kg mass)."""
    items = tuple(b if isinstance(b, Box) else Box(*map(float, b), 1.0) for b in boxes)
    return EpisodeSpec(dataset, "train", group, items, ContainerSpec(*container), threshold, 0)


@pytest.fixture
def random_spec() -> EpisodeSpec:
    """80 random boxes in the Repetitive container (deterministic)."""
    rng = np.random.default_rng(7)
    dims = rng.integers(15, 55, size=(80, 3))
    return make_spec([tuple(map(float, d)) for d in dims], container=(134, 125, 100), dataset="synthetic")
