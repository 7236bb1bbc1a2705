"""Vectorised placement candidates on the heightmap, shared by the heightmap-based policies."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from robobpp.core import Action, Observation, drop_height_map
from robobpp.core.feasibility import TOLERANCE_CM


@dataclass(frozen=True, slots=True)
class CandidateMap:
    """For one orientation: resting height and feasibility of every integer position (x, y).

    ``z[x, y]`` is where the box's bottom would rest with its min corner at (x, y) cm; ``feasible`` says the
    box then stays inside the container (bounds are implied by the map's shape).
    """

    orientation: int
    length: float
    width: float
    height: float
    z: np.ndarray
    feasible: np.ndarray


def candidate_maps(obs: Observation) -> Iterator[CandidateMap]:
    """One :class:`CandidateMap` per allowed orientation (skipping ones where the box cannot fit at all)."""
    limit = obs.container.height + TOLERANCE_CM
    for orientation in obs.orientations:
        length, width, height = obs.box.dims(orientation)
        if length > obs.container.length + TOLERANCE_CM or width > obs.container.width + TOLERANCE_CM:
            continue
        z = drop_height_map(obs.heightmap, length, width)
        if z.size == 0:
            continue
        yield CandidateMap(orientation, length, width, height, z, z + height <= limit)


def argmin_placement(
    obs: Observation, score: Callable[[CandidateMap, np.ndarray, np.ndarray], np.ndarray]
) -> Action | None:
    """The feasible position and orientation of least ``score(cand, xs, ys)`` over every candidate map.

    ``xs``/``ys`` are broadcastable column/row index arrays of the map's positions. Ties go to the earlier
    orientation, then the smaller x, then y. ``None`` when no position is feasible in any orientation.
    """
    best: tuple[float, int, int, int] | None = None
    for cand in candidate_maps(obs):
        nx, ny = cand.z.shape
        cost = np.where(cand.feasible, score(cand, np.arange(nx)[:, None], np.arange(ny)[None, :]), np.inf)
        flat = int(np.argmin(cost))
        value = float(cost.flat[flat])
        if np.isfinite(value) and (best is None or value < best[0]):
            x, y = divmod(flat, ny)
            best = (value, x, y, cand.orientation)
    return None if best is None else Action(float(best[1]), float(best[2]), best[3])
