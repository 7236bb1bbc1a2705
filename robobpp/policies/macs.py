"""MACS, maximise accessible convex space (Hu et al. 2020, TAP-Net; RoboBPP paper, Algorithm "MACS")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.policies.candidates import first_placement
from robobpp.policies.ems import HEIGHT_EPS, EmsPolicy, ems_candidates


class MACS(EmsPolicy):
    """Maximise accessible convex space, as the reference implements it: over every EMS, orientation where the
    box fits inside the space, and the space's four bottom corners, maximise

    ``Σ_{h = 0, 1, …, ⌈z⌉ − 1} A_h``

    where ``z`` is where the box comes to rest and ``A_h`` the area of the largest empty rectangle at the
    1 cm level ``h`` of the container *after* placing the box (TAP-Net's score, its levels counted only below
    the resting height). A cell is empty at level h when the heightmap there is ≤ h. A box on the floor
    scores 0, so MACS stacks wherever something lets it; that is the reference's rule, and why MACS ranks
    last in the paper. Equal scores go to the lower space, then back-left, then orientation 0, then the
    corner order (back-left, back-right, front-left, front-right; the reference: its list order).

    ``A_h`` comes from the EMS without rasterising: the largest empty rectangle at level h is the largest EMS
    with floor ≤ h, and a space the box cuts at that level keeps its four side slabs.
    """

    name = "macs"

    def act(self, obs: Observation) -> Action | None:
        ems = self.spaces(obs)
        cands = ems_candidates(obs, ems, corners=4, dedupe=False)
        if len(cands) == 0:
            return None
        order = np.argsort(ems.z0, kind="stable")
        r, z0 = ems.rects[order], ems.z0[order]
        area = ((r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])).astype(np.float64)
        bx0, by0 = cands.x[:, None], cands.y[:, None]
        bx1, by1 = bx0 + cands.lc[:, None], by0 + cands.wc[:, None]
        x0, y0, x1, y1 = (r[None, :, i] for i in range(4))
        cut = (x0 < bx1) & (x1 > bx0) & (y0 < by1) & (y1 > by0)  # (C, E): at levels below the rest
        dx, dy = x1 - x0, y1 - y0
        side = np.maximum.reduce(
            [
                np.clip(bx0 - x0, 0, None) * dy,
                np.clip(x1 - bx1, 0, None) * dy,
                np.clip(by0 - y0, 0, None) * dx,
                np.clip(y1 - by1, 0, None) * dx,
            ]
        )
        # largest rectangle among the spaces with floor ≤ each level: a running max over the sorted floors
        level_area = np.maximum.accumulate(np.where(cut, side, area[None, :]), axis=1)
        levels = np.unique(z0)
        last = np.searchsorted(z0, levels + HEIGHT_EPS, side="right") - 1
        best = level_area[:, last]  # (C, K): A_h for h from each distinct floor up to the next
        starts = np.ceil(levels - HEIGHT_EPS)
        ends = np.ceil(np.append(levels[1:], ems.height) - HEIGHT_EPS)
        rest = np.ceil(cands.z - HEIGHT_EPS)[:, None]
        count = np.clip(np.minimum(ends[None, :], rest) - starts[None, :], 0, None)  # integer levels h < z
        score = (count * best).sum(axis=1)
        corner = (cands.x != ems.rects[cands.ems, 0]).astype(int) + 2 * (cands.y != ems.rects[cands.ems, 1])
        ranked = np.lexsort(
            (corner, cands.orientation, cands.y, cands.x, ems.z0[cands.ems], -np.round(score, 6))
        )
        return first_placement(ranked, cands.x, cands.y, cands.orientation)
