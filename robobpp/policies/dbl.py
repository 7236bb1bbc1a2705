"""DBL, deep-bottom-left (Karabulut & İnceoğlu 2004; the RoboBPP paper's strongest simple heuristic)."""

from __future__ import annotations

from robobpp.core import Action, Observation
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import argmin_placement, unrotated_range


class DBL(BasePolicy):
    """Deep-bottom-left: over every 1 cm cell and both orientations, minimise ``100·z + x + y`` among the
    feasible placements (inside the container, below its top).

    The box goes as low as it can, then as far back (small x) and left (small y) as it can — "the lowest
    and most-left feasible position" of the paper. As in the reference's loops, ties go to the smaller x,
    then y, then orientation 0, and positions range over ``x ≤ L − l``, ``y ≤ W − w`` with the box's
    *unrotated* footprint ``l × w`` in both orientations (see docs/baselines.md).
    """

    name = "dbl"

    def act(self, obs: Observation) -> Action | None:
        return argmin_placement(obs, lambda cand, xs, ys: 100.0 * cand.z + xs + ys, unrotated_range(obs))
