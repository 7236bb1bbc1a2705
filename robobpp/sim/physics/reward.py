"""The paper's stability-shaped training reward (appendix: "Reward with Stability and Local Stability")."""

from __future__ import annotations

import math
from collections.abc import Iterable


def stability_reward(
    volume_ratio: float, static_stability: float | None, offsets_m: Iterable[float]
) -> float:
    """``10 × volume ratio + 0.01 × static stability − mean position offset`` (metres).

    ``volume_ratio`` is the placed box's volume over the container's; ``offsets_m`` are the distances between
    planned and actual positions of the placed boxes (empty: no offset). A missing static stability (a step
    that placed nothing) counts 0. Pure, so the Gymnasium env and any trainer can call it.
    """
    values = [float(o) for o in offsets_m]
    for value in (volume_ratio, *values):
        if not math.isfinite(value):
            raise ValueError(f"stability_reward needs finite inputs, got {value!r}")
    mean_offset = sum(values) / len(values) if values else 0.0
    return 10.0 * float(volume_ratio) + 0.01 * float(static_stability or 0.0) - mean_offset
