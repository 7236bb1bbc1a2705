"""Synthetic episode sets with the real datasets' interface: offline tests, stress and adversarial sizes.

``synthetic_episode_specs`` draws boxes uniformly within size ranges (optionally on a grid); profiles give
ready-made extremes (``tiny`` boxes, ``huge`` ones that fit no container). ``load_specs`` reads a JSON
episode set or a CSV of boxes and REFUSES zero, negative or non-finite sizes with a clear error: invalid
boxes are a load-time failure, never an episode-time surprise.
"""

from __future__ import annotations

import math
import zlib
from pathlib import Path

import numpy as np

from robobpp.core import Box, ContainerSpec, EpisodeSpec
from robobpp.datasets.errors import SpecFileError
from robobpp.datasets.registry import GROUP_SIZE, get_dataset
from robobpp.datasets.specfile import read_csv, read_json, write_specs

Range = tuple[float, float]

#: Size ranges (cm) per profile: (length, width, height).
PROFILES: dict[str, tuple[Range, Range, Range]] = {
    "default": ((10.0, 60.0), (10.0, 60.0), (5.0, 50.0)),
    "tiny": ((0.5, 2.0), (0.5, 2.0), (0.5, 2.0)),
    "huge": ((300.0, 600.0), (200.0, 400.0), (150.0, 300.0)),
}

__all__ = ["PROFILES", "load_specs", "save_specs", "synthetic_episode_specs"]


def _check_range(name: str, bounds: Range) -> Range:
    low, high = (float(b) for b in bounds)
    if not (math.isfinite(low) and math.isfinite(high)) or low <= 0 or high < low:
        raise ValueError(f"{name} must be finite with 0 < low <= high, got {bounds!r}")
    return low, high


def synthetic_episode_specs(
    groups: int = 1,
    seed: int = 0,
    *,
    container: ContainerSpec | str = "repetitive",
    group_size: int = GROUP_SIZE,
    profile: str = "default",
    length_range: Range | None = None,
    width_range: Range | None = None,
    height_range: Range | None = None,
    resolution: float | None = 1.0,
    density_kg_m3: float = 250.0,
    collapse_threshold_cm: float | None = None,
    dataset: str = "synthetic",
    split: str = "train",
) -> list[EpisodeSpec]:
    """``groups`` episodes of uniformly drawn boxes; group i depends only on (seed, i).

    ``container`` is a ContainerSpec or a dataset name (its container and threshold are used).
    ``resolution`` rounds sizes up to a multiple of it (1 cm by default, like most real data); ``None``
    keeps continuous sizes. Masses follow ``density_kg_m3``.
    """
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; expected one of {', '.join(PROFILES)}")
    if isinstance(container, str):
        registry = get_dataset(container)
        box_container, threshold = registry.container, registry.collapse_threshold_cm
    else:
        box_container, threshold = container, 7.0
    if collapse_threshold_cm is not None:
        threshold = collapse_threshold_cm
    if not math.isfinite(threshold) or threshold <= 0:
        raise ValueError(f"collapse_threshold_cm must be finite and > 0, got {threshold!r}")
    if not math.isfinite(density_kg_m3) or density_kg_m3 <= 0:
        raise ValueError(f"density_kg_m3 must be finite and > 0, got {density_kg_m3!r}")
    if resolution is not None and (not math.isfinite(resolution) or resolution <= 0):
        raise ValueError(f"resolution must be finite and > 0 or None, got {resolution!r}")
    if groups < 0 or group_size < 1 or seed < 0:
        raise ValueError(f"need groups >= 0, group_size >= 1, seed >= 0; got {groups}, {group_size}, {seed}")
    defaults = PROFILES[profile]
    ranges = [
        _check_range(name, given or default)
        for name, given, default in zip(
            ("length_range", "width_range", "height_range"),
            (length_range, width_range, height_range),
            defaults,
            strict=True,
        )
    ]
    salt = zlib.crc32(b"robobpp-synthetic")
    out = []
    for group in range(groups):
        rng = np.random.default_rng(np.random.SeedSequence(entropy=seed, spawn_key=(salt, group)))
        dims = np.stack([rng.uniform(low, high, group_size) for low, high in ranges], axis=1)
        if resolution is not None:
            dims = np.maximum(np.ceil(dims / resolution - 1e-9) * resolution, resolution)
        boxes = tuple(
            Box(float(l_), float(w_), float(h_), float(l_ * w_ * h_ * 1e-6 * density_kg_m3))
            for l_, w_, h_ in dims
        )
        out.append(EpisodeSpec(dataset, split, group, boxes, box_container, float(threshold), seed))
    return out


def save_specs(path: Path, specs: list[EpisodeSpec]) -> None:
    """Write episodes in the JSON episode-set format (what ``load_specs`` reads back)."""
    write_specs(Path(path), specs)


def load_specs(
    path: Path,
    *,
    container: ContainerSpec | str | None = None,
    collapse_threshold_cm: float | None = None,
    dataset: str = "synthetic",
) -> list[EpisodeSpec]:
    """Episodes from ``.json`` (self-describing) or ``.csv`` (rows ``group,length,width,height[,mass]``).

    A CSV needs ``container`` (a ContainerSpec or a dataset name). Raises SpecFileError on invalid input.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".json":
        return read_json(path)
    if suffix == ".csv":
        if container is None:
            raise SpecFileError(
                f"{path}: a CSV episode set needs container= (a ContainerSpec or a dataset name)"
            )
        threshold = 7.0
        if isinstance(container, str):
            registry = get_dataset(container)
            container, threshold = registry.container, registry.collapse_threshold_cm
        if collapse_threshold_cm is not None:
            threshold = collapse_threshold_cm
        return read_csv(path, container, threshold, dataset)
    raise SpecFileError(f"{path}: unknown episode-set format {suffix!r}; expected .json or .csv")
