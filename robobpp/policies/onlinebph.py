"""OnlineBPH, the online packing heuristic of Ha et al. (2017) (RoboBPP paper, Algorithm "OnlineBPH")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.core.feasibility import TOLERANCE_CM
from robobpp.core.heightmap import cells_spanned
from robobpp.policies.ems import EmsPolicy


class OnlineBPH(EmsPolicy):
    """First fit over EMS in deep-bottom-left order: sort the spaces by floor height (lowest first), then
    back (x0), then left (y0) (spaces sharing that corner: the larger first); take the first space the box fits in, with the first orientation (0, then 1)
    that fits, at the space's back-left-bottom corner.

    Ha et al. evaluate bins × items × EMS × rotations over several open bins; here there is one bin and one
    item, so the search reduces to spaces × orientations in DBL order ("sort spaces by depth, select the
    first feasible position"). The box may rest below the space's floor when its footprint misses the cells
    that set it; that is still inside the space.
    """

    name = "onlinebph"

    def act(self, obs: Observation) -> Action | None:
        ems = self.spaces(obs)
        order = np.lexsort((-ems.dy, -ems.dx, ems.rects[:, 1], ems.rects[:, 0], ems.z0))
        fits = []
        for orientation in obs.orientations:
            length, width, height = obs.box.dims(orientation)
            x0, y0 = ems.rects[:, 0], ems.rects[:, 1]
            fit = (
                (ems.dx >= cells_spanned(length))
                & (ems.dy >= cells_spanned(width))
                & (ems.dz >= height - TOLERANCE_CM)
                & (x0 + length <= obs.container.length + TOLERANCE_CM)
                & (y0 + width <= obs.container.width + TOLERANCE_CM)
            )
            fits.append(fit[order])
        if not fits:
            return None
        any_fit = np.logical_or.reduce(fits)
        if not any_fit.any():
            return None
        first = int(np.argmax(any_fit))
        k = int(order[first])
        orientation = next(o for o, f in zip(obs.orientations, fits, strict=True) if f[first])
        return Action(float(ems.rects[k, 0]), float(ems.rects[k, 1]), orientation)
