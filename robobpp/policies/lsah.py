"""LSAH, least surface area heuristic (Hu et al. 2017; RoboBPP paper, Algorithm "LASH")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.core.feasibility import cell_rect
from robobpp.policies.candidates import first_placement
from robobpp.policies.ems import EmsPolicy, ems_candidates


class LSAH(EmsPolicy):
    """Least surface area, as the reference implements it: over every EMS and orientation where the box fits
    inside the space (the box at the space's back-left-bottom corner), minimise

    ``X·Y + (z + h)·Y + (z + h)·X``

    with ``X × Y`` the footprint of the bounding rectangle of the packed boxes and the candidate (from the
    smallest to the largest x and y any of them occupies) and ``z + h`` the candidate's own top. Equal scores
    go to the tighter space: the smaller least slack ``min(space − box)`` over the three axes (the reference's
    tie-break), then the lower space, then back-left, then orientation 0 (the reference: its list order). The paper examines six orientations; the robot allows the two upright.
    """

    name = "lsah"

    def act(self, obs: Observation) -> Action | None:
        ems = self.spaces(obs)
        cands = ems_candidates(obs, ems, corners=1, dedupe=False)
        if len(cands) == 0:
            return None
        nx, ny = obs.heightmap.shape
        lo_x, lo_y, hi_x, hi_y = nx, ny, 0, 0  # the reference starts from an empty rectangle
        for p in obs.placed:
            x0, y0, x1, y1 = cell_rect(p.x, p.y, p.length, p.width)
            lo_x, lo_y, hi_x, hi_y = min(lo_x, x0), min(lo_y, y0), max(hi_x, x1), max(hi_y, y1)
        big_x = np.maximum(cands.x + cands.lc, hi_x) - np.minimum(cands.x, lo_x)
        big_y = np.maximum(cands.y + cands.wc, hi_y) - np.minimum(cands.y, lo_y)
        top = cands.z + cands.h
        score = big_x * big_y + top * big_y + top * big_x
        r = ems.rects[cands.ems]
        slack = np.minimum.reduce(
            [r[:, 2] - r[:, 0] - cands.lc, r[:, 3] - r[:, 1] - cands.wc, ems.dz[cands.ems] - cands.h]
        )
        order = np.lexsort(
            (cands.orientation, cands.y, cands.x, ems.z0[cands.ems], np.round(slack, 9), np.round(score, 6))
        )
        return first_placement(order, cands.x, cands.y, cands.orientation)
