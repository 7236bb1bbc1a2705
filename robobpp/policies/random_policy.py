"""Random: a uniformly random feasible placement — the floor of the scale."""

from __future__ import annotations

import zlib

import numpy as np

from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import candidate_maps, first_placement


class RandomPolicy(BasePolicy):
    """Pick uniformly among all feasible (x, y, orientation) on the 1 cm grid. Not from the paper: the floor
    of the scale (the reference's ``random`` does the same over its full coordinate grid).

    The placements that fit (inside the container, below its top: the environment's action mask) are shuffled
    and the first is taken. Seeded from ``seed`` and the episode id, so the same episode gives the same
    placements.
    """

    name = "random"

    def __init__(self, seed: int = 0) -> None:
        self.seed = seed
        self._rng = np.random.default_rng(seed)

    def reset(self, info: EpisodeInfo) -> None:
        self._rng = np.random.default_rng([self.seed, zlib.crc32(info.episode_id.encode())])

    def act(self, obs: Observation) -> Action | None:
        parts = []
        for cand in candidate_maps(obs):
            px, py = np.nonzero(cand.fits)
            parts.append((px, py, np.full(len(px), cand.orientation), cand.z[px, py]))
        if not parts:
            return None
        xs, ys, os_, zs = (np.concatenate(c) for c in zip(*parts, strict=True))
        return first_placement(self._rng.permutation(len(xs)), xs, ys, os_)
