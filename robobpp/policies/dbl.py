"""DBL, deep-bottom-left (Karabulut & İnceoğlu 2004; the RoboBPP paper's strongest simple heuristic)."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import candidate_maps


class DBL(BasePolicy):
    """Deep-bottom-left: over every 1 cm cell and both orientations, minimise ``100·z + x + y``.

    The box goes as low as it can, then as far back (small x) and left (small y) as it can — "the lowest
    and most-left feasible position" of the paper. Ties go to orientation 0, then the smallest x, then y.
    """

    name = "dbl"

    def act(self, obs: Observation) -> Action | None:
        best: tuple[float, int, int, int] | None = None
        for cand in candidate_maps(obs):
            nx, ny = cand.z.shape
            cost = 100.0 * cand.z + np.arange(nx)[:, None] + np.arange(ny)[None, :]
            cost = np.where(cand.feasible, cost, np.inf)
            flat = int(np.argmin(cost))
            value = float(cost.flat[flat])
            if np.isfinite(value) and (best is None or value < best[0]):
                x, y = divmod(flat, ny)
                best = (value, x, y, cand.orientation)
        if best is None:
            return None
        return Action(float(best[1]), float(best[2]), best[3])
