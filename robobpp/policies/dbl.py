"""DBL, deep-bottom-left (Karabulut & İnceoğlu 2004; the RoboBPP paper's strongest simple heuristic)."""

from __future__ import annotations

from robobpp.core import Action, Observation
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import argmin_placement


class DBL(BasePolicy):
    """Deep-bottom-left: over every 1 cm cell and both orientations, minimise ``100·z + x + y``.

    The box goes as low as it can, then as far back (small x) and left (small y) as it can — "the lowest
    and most-left feasible position" of the paper. Ties go to orientation 0, then the smallest x, then y.
    """

    name = "dbl"

    def act(self, obs: Observation) -> Action | None:
        return argmin_placement(obs, lambda cand, xs, ys: 100.0 * cand.z + xs + ys)
