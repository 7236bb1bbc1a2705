"""HM, heightmap minimisation (Wang & Hauser 2019; RoboBPP paper, Algorithm "HM")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.core.heightmap import cells_spanned
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import CandidateMap, argmin_placement, unrotated_range


def window_sums(grid: np.ndarray, lc: int, wc: int) -> np.ndarray:
    """Sum of ``grid`` over every ``lc × wc`` window (summed-area table), shape like ``drop_height_map``."""
    table = np.zeros((grid.shape[0] + 1, grid.shape[1] + 1))
    np.cumsum(np.cumsum(grid, axis=0), axis=1, out=table[1:, 1:])
    return table[lc:, wc:] - table[:-lc, wc:] - table[lc:, :-wc] + table[:-lc, :-wc]


class HM(BasePolicy):
    """Heightmap minimisation: over every 1 cm position and both orientations, minimise
    ``x + y + 100 · (heightmap volume after placing)``.

    The paper's pseudocode scores ``i + j + 100·ΣS[i:i+l, j:j+w]`` with S the heightmap after the box is
    placed ("selecting placements that minimize the increase in occupied volume"). The volume before is the
    same for every candidate, so the policy minimises the *added* volume, ``cells·(z + h) − Σ heightmap`` over
    the footprint: the box's own volume plus the gap it traps under itself. In cm³ that term dominates, so
    ``x + y`` only breaks ties (back-left first). Candidates are the feasible placements; ties and the
    position range follow the reference's loops, as for DBL.
    """

    name = "hm"

    def act(self, obs: Observation) -> Action | None:
        def score(cand: CandidateMap, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
            lc, wc = cells_spanned(cand.length), cells_spanned(cand.width)
            added = lc * wc * (cand.z + cand.height) - window_sums(obs.heightmap, lc, wc)
            cost: np.ndarray = 100.0 * added + xs + ys
            return cost

        return argmin_placement(obs, score, unrotated_range(obs))
