"""BR, best regularity (Zhao et al. 2021's heuristic baseline; RoboBPP paper, Algorithm "BR")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.core.heightmap import cells_spanned
from robobpp.policies.candidates import first_placement
from robobpp.policies.ems import EmsPolicy, ems_candidates

#: Bonus when every known item type still fits the space (the reference's value).
ALL_FIT_BONUS = 10.0


class BR(EmsPolicy):
    """Best regularity, as the reference implements it: over every EMS and orientation where the box fits
    inside the space (at the space's back-left-bottom corner), maximise the space's score

    ``volume of the space + number of known item types that fit in it (+ 10 when all of them do)``

    — "space utilization score" and "count items that could fit in the space" of the paper. The score is the
    space's, so among a space's placements orientation 0 comes first (as in the reference's loop); equal
    scores of different spaces go to the lower space, then back-left (the reference: its list order). An item type fits when its length, width and height (as given, unturned) fit the space.
    Known item types are the distinct sizes this policy has been asked to place in the episode so far, plus
    the lookahead: the reference reads the dataset's item set, which an online policy does not have.
    """

    name = "br"

    def __init__(self) -> None:
        super().__init__()
        self._seen: dict[tuple[int, int, float], None] = {}

    def reset(self, info: EpisodeInfo) -> None:
        super().reset(info)
        self._seen = {}

    def act(self, obs: Observation) -> Action | None:
        for box in (obs.box, *obs.lookahead):
            self._seen[(cells_spanned(box.length), cells_spanned(box.width), box.height)] = None
        ems = self.spaces(obs)
        cands = ems_candidates(obs, ems, corners=1, dedupe=False)
        if len(cands) == 0:
            return None
        items = np.array(list(self._seen), dtype=np.float64)  # (T, 3)
        fit = (
            (items[None, :, 0] <= ems.dx[:, None])
            & (items[None, :, 1] <= ems.dy[:, None])
            & (items[None, :, 2] <= ems.dz[:, None] + 1e-6)
        ).sum(axis=1)
        space = ems.dx * ems.dy * ems.dz + fit + ALL_FIT_BONUS * (fit == len(items))
        score = space[cands.ems]
        order = np.lexsort((cands.orientation, cands.y, cands.x, ems.z0[cands.ems], -np.round(score, 6)))
        return first_placement(order, cands.x, cands.y, cands.orientation)
