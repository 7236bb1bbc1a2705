"""LSAH, least surface area heuristic (Hu et al. 2017; RoboBPP paper, Algorithm "LASH")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.policies.candidates import first_supported
from robobpp.policies.ems import HEIGHT_EPS, EmsPolicy, ems_candidates


class LSAH(EmsPolicy):
    """Least surface area: over every EMS and orientation (the box at the EMS's back-left-bottom corner),
    minimise the surface area ``2(XY + XZ + YZ)`` of the bounding box of the packed items after placing.

    The bounding box is anchored at the container origin (the corner packing starts from), so it is
    ``[0, X] × [0, Y] × [0, Z]`` with X, Y the far edges of the occupied cells and Z the highest top. The paper
    examines six orientations; the robot allows the two upright ones. Ties: lower resting z, then smaller
    ``x + y``, then smaller x, then orientation 0.
    """

    name = "lsah"

    def act(self, obs: Observation) -> Action | None:
        cands = ems_candidates(obs, self.spaces(obs), corners=1)
        if len(cands) == 0:
            return None
        hm = obs.heightmap
        occupied = hm > HEIGHT_EPS
        rows, cols = np.flatnonzero(occupied.any(axis=1)), np.flatnonzero(occupied.any(axis=0))
        bx = rows[-1] + 1 if rows.size else 0
        by = cols[-1] + 1 if cols.size else 0
        bz = float(hm.max()) if hm.size else 0.0
        big_x = np.maximum(bx, cands.x + cands.lc)
        big_y = np.maximum(by, cands.y + cands.wc)
        big_z = np.maximum(bz, cands.z + cands.h)
        area = 2.0 * (big_x * big_y + big_x * big_z + big_y * big_z)
        order = np.lexsort((cands.orientation, cands.x, cands.x + cands.y, cands.z, area))
        return first_supported(obs, order, cands.x, cands.y, cands.orientation, cands.z)
