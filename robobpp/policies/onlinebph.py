"""OnlineBPH, the online packing heuristic of Ha et al. (2017) (RoboBPP paper, Algorithm "OnlineBPH")."""

from __future__ import annotations

import math

import numpy as np

from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.core.feasibility import TOLERANCE_CM
from robobpp.core.heightmap import cells_spanned
from robobpp.policies.ems import EmsPolicy


class OnlineBPH(EmsPolicy):
    """First fit over the EMS in the reference's order: sort the spaces by floor height, then y, then x (their
    back-left-bottom corner, lowest first); take the first space and orientation (0, then 1) where the box,
    dropped at the space's corner, is feasible — inside the container, below its top (no support test, as in
    the reference).

    As in the reference, the box is not required to fit inside the space: it is dropped at the space's corner
    and rests wherever the heightmap under its footprint lets it. Ha et al. search bins × items × EMS ×
    rotations; with one bin and one item this is the whole search.

    Spaces with a side (length, width or height) shorter than the smallest item side are not listed, as the
    reference's EMS keep only spaces at least that large. The reference takes the smallest side of the
    dataset's item set; an online policy does not have it, so this is the smallest side (whole-cell length
    and width, height) of the boxes it has been asked to place in the episode so far, plus the lookahead.
    Only OnlineBPH notices the bound: the other EMS heuristics need the box to fit inside the space.
    """

    name = "onlinebph"

    def __init__(self) -> None:
        super().__init__()
        self._smallest = math.inf

    def reset(self, info: EpisodeInfo) -> None:
        super().reset(info)
        self._smallest = math.inf

    def act(self, obs: Observation) -> Action | None:
        for box in (obs.box, *obs.lookahead):
            self._smallest = min(
                self._smallest, cells_spanned(box.length), cells_spanned(box.width), box.height
            )
        ems = self.spaces(obs)
        s = self._smallest
        usable = np.flatnonzero((ems.dx >= s) & (ems.dy >= s) & (ems.dz >= s - 1e-6))
        order = usable[np.lexsort((ems.rects[usable, 0], ems.rects[usable, 1], ems.z0[usable]))]
        hm = obs.heightmap
        container = obs.container
        seen: set[tuple[int, int]] = set()
        for k in order:
            x, y = int(ems.rects[k, 0]), int(ems.rects[k, 1])
            if (x, y) in seen:  # another space with the same corner: the same placements
                continue
            seen.add((x, y))
            for orientation in obs.orientations:
                length, width, height = obs.box.dims(orientation)
                if x + length > container.length + TOLERANCE_CM or y + width > container.width + TOLERANCE_CM:
                    continue
                z = float(hm[x : x + cells_spanned(length), y : y + cells_spanned(width)].max())
                if z + height > container.height + TOLERANCE_CM:
                    continue
                return Action(float(x), float(y), orientation)
        return None
