"""Where a work item's :class:`EpisodeSpec` comes from.

``test`` split: the private evaluation set built on the server (``datasets_private/``), never served.
``holdout``: the private pool's second draw (``datasets_private/holdout/``), played by verifications only.
``train`` split: the public groups, drawn with seed 0 (anyone can reproduce them with the SDK).
``ROBOBPP_SPEC_PROVIDER=module:function`` replaces both (offline tests, synthetic demos).
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

from robobpp.core import EpisodeSpec

Provider = Callable[[str, str, int, int], EpisodeSpec]


class SpecUnavailableError(RuntimeError):
    """The episode's boxes cannot be loaded (private split missing, data not fetched...)."""


@lru_cache(maxsize=8)
def _provider(path: str) -> Provider:
    module, _, attr = path.partition(":")
    provider: Provider = getattr(importlib.import_module(module), attr)
    return provider


@lru_cache(maxsize=16)
def _private(dataset: str, root: str) -> tuple[EpisodeSpec, ...]:
    from robobpp import datasets

    load_private = getattr(datasets, "load_private", None)
    if load_private is None:
        raise SpecUnavailableError(
            "this installation cannot load a private split (robobpp.datasets.load_private)"
        )
    return tuple(load_private(dataset, Path(root)))


@lru_cache(maxsize=16)
def _public(dataset: str, groups: int) -> tuple[EpisodeSpec, ...]:
    from robobpp import datasets

    episode_specs = getattr(datasets, "episode_specs", None)
    if episode_specs is None:
        from robobpp.datasets import sampling

        episode_specs = sampling.episode_specs
    return tuple(episode_specs(dataset, "train", groups=groups, seed=0))


def episode_spec(
    dataset: str,
    split: str,
    group: int,
    *,
    groups: int,
    private_dir: Path,
    provider: str = "",
    max_boxes: int = 0,
) -> EpisodeSpec:
    """The group's episode; ``max_boxes`` > 0 keeps its first boxes only (the demo's short episodes)."""
    spec = _spec(dataset, split, group, groups=groups, private_dir=private_dir, provider=provider)
    if 0 < max_boxes < len(spec.boxes):
        spec = dataclasses.replace(spec, boxes=spec.boxes[:max_boxes])
    return spec


def _spec(
    dataset: str, split: str, group: int, *, groups: int, private_dir: Path, provider: str
) -> EpisodeSpec:
    if provider:
        return _provider(provider)(dataset, split, group, groups)
    if split == "test":
        specs = _private(dataset, str(private_dir))
    elif split == "holdout":  # the private pool's second draw, played by verifications only
        from robobpp.datasets.private import HOLDOUT_DIR

        specs = _private(dataset, str(Path(private_dir) / HOLDOUT_DIR))
    else:
        specs = _public(dataset, groups)
    if not 0 <= group < len(specs):
        raise SpecUnavailableError(f"{dataset}/{split} has {len(specs)} groups; group {group} does not exist")
    return specs[group]


#: Boxes per episode of :func:`offline_spec` (small on purpose: tests and offline demos).
OFFLINE_BOXES = 12


def offline_spec(dataset: str, split: str, group: int, groups: int) -> EpisodeSpec:
    """A deterministic synthetic episode in the dataset's real container (no data download needed).

    Use with ``ROBOBPP_SPEC_PROVIDER=robobpp.worker.specs:offline_spec`` for tests and offline demos;
    the leaderboard of a real deployment never uses it.
    """
    import zlib

    import numpy as np

    from robobpp.core import Box
    from robobpp.datasets import get_dataset

    ds = get_dataset(dataset)
    seed = zlib.crc32(f"{dataset}/{split}/{group}".encode())
    # The hold-out draw has its own boxes but looks like the test split (same ids), as the real one does.
    label = "test" if split == "holdout" else split
    rng = np.random.default_rng(seed)
    c = ds.container
    dims = rng.uniform(0.15, 0.45, size=(OFFLINE_BOXES, 3)) * np.array([c.length, c.width, c.height * 0.5])
    boxes = tuple(
        Box(float(round(a)), float(round(b)), float(round(h)), float(round(rng.uniform(1, 8), 2)))
        for a, b, h in dims
    )
    return EpisodeSpec(dataset, label, group, boxes, c, ds.collapse_threshold_cm, seed)
