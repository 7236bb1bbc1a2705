"""MACS, maximise accessible convex space (Hu et al. 2020, TAP-Net; RoboBPP paper, Algorithm "MACS")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.policies.candidates import first_supported
from robobpp.policies.ems import HEIGHT_EPS, EmsPolicy, ems_candidates


class MACS(EmsPolicy):
    """Maximise the accessible convex space left after placing: over every EMS, orientation and bottom corner
    of the space, maximise ``∫₀ᴴ A(z) dz``, where ``A(z)`` is the area of the largest empty rectangle at
    height z that is open to the top (the largest free cuboid cross-section a later box can be lowered into).

    This is TAP-Net's score (for each height level, the largest empty rectangle, summed over levels), taken
    continuously. It is computed from the EMS without touching the heightmap: the largest free rectangle
    at height z is the largest EMS with floor ≤ z, and placing a box only changes the spaces it cuts — each
    becomes its four side slabs (same floor) and one slab above the box (floor at the box top). Ties: lower
    z, then back-left, then orientation 0.
    """

    name = "macs"

    def act(self, obs: Observation) -> Action | None:
        ems = self.spaces(obs)
        cands = ems_candidates(obs, ems, corners=4)
        if len(cands) == 0:
            return None
        height = obs.container.height
        order = np.argsort(ems.z0, kind="stable")
        r, z0 = ems.rects[order], ems.z0[order]
        area = ((r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])).astype(np.float64)
        bx0, by0 = cands.x[:, None], cands.y[:, None]
        bx1, by1 = bx0 + cands.lc[:, None], by0 + cands.wc[:, None]
        top = (cands.z + cands.h)[:, None]
        x0, y0, x1, y1 = (r[None, :, i] for i in range(4))
        cut = (x0 < bx1) & (x1 > bx0) & (y0 < by1) & (y1 > by0) & (z0[None, :] < top - HEIGHT_EPS)  # (C, E)
        dx, dy = x1 - x0, y1 - y0
        side = np.maximum.reduce(
            [
                np.clip(bx0 - x0, 0, None) * dy,
                np.clip(x1 - bx1, 0, None) * dy,
                np.clip(by0 - y0, 0, None) * dx,
                np.clip(y1 - by1, 0, None) * dx,
            ]
        )
        level_area = np.maximum.accumulate(
            np.where(cut, side, area[None, :]), axis=1
        )  # running max over floors
        levels = np.unique(z0)
        last = np.searchsorted(z0, levels + HEIGHT_EPS, side="right") - 1
        best = level_area[:, last]  # (C, K): largest rectangle from each level up to the next
        ends = np.append(levels[1:], height)
        above = np.where(cut, area[None, :], 0.0).max(axis=1)[:, None]  # slab above the box: its cut spaces
        overlap = np.clip(ends[None, :] - np.maximum(levels[None, :], top), 0, None)
        seg = (ends - levels)[None, :]
        score = ((seg - overlap) * best + overlap * np.maximum(best, above)).sum(axis=1)
        order = np.lexsort((cands.orientation, cands.x, cands.x + cands.y, cands.z, -np.round(score, 6)))
        return first_supported(obs, order, cands.x, cands.y, cands.orientation, cands.z)
