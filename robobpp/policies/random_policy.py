"""Random: a uniformly random feasible placement — the floor of the scale."""

from __future__ import annotations

import zlib

import numpy as np

from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import candidate_maps


class RandomPolicy(BasePolicy):
    """Pick uniformly among all feasible (x, y, orientation) on the 1 cm grid.

    Seeded from ``seed`` and the episode id, so the same episode gives the same placements.
    """

    name = "random"

    def __init__(self, seed: int = 0) -> None:
        self.seed = seed
        self._rng = np.random.default_rng(seed)

    def reset(self, info: EpisodeInfo) -> None:
        self._rng = np.random.default_rng([self.seed, zlib.crc32(info.episode_id.encode())])

    def act(self, obs: Observation) -> Action | None:
        options = [(c.orientation, np.flatnonzero(c.feasible), c.z.shape[1]) for c in candidate_maps(obs)]
        total = sum(len(flat) for _, flat, _ in options)
        if total == 0:
            return None
        pick = int(self._rng.integers(total))
        for orientation, flat, ny in options:
            if pick < len(flat):
                x, y = divmod(int(flat[pick]), ny)
                return Action(float(x), float(y), orientation)
            pick -= len(flat)
        raise AssertionError("unreachable")
