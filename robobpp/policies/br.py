"""BR, best regularity (Zhao et al. 2021's heuristic baseline; RoboBPP paper, Algorithm "BR")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.core.heightmap import cells_spanned
from robobpp.policies.candidates import first_supported
from robobpp.policies.ems import EmsPolicy, ems_candidates

#: How many distinct recent box sizes stand for "typical items".
TYPICAL_ITEMS = 32


class BR(EmsPolicy):
    """Best regularity: over every EMS, orientation and bottom corner of the space, maximise

    ``utility = w_fit · fit + w_count · still_fit − w_height · top / H``

    - ``fit``: footprint of the box / floor area of the space — a box that fills its space keeps the packed
      volume regular instead of leaving slivers;
    - ``still_fit``: share of the typical items that still fit in what is left of the chosen space (the four
      slabs beside the box and the slab above it) — "count items that could fit in the space";
    - ``top / H``: the box's top relative to the container height, so regular layers grow from the floor.

    Typical items are the distinct sizes of the last :data:`TYPICAL_ITEMS` boxes this policy was asked to
    place in the episode (plus any lookahead), since an online policy knows no more. Ties: lower z, then
    back-left. Weights default to 1.
    """

    name = "br"

    def __init__(self, w_fit: float = 1.0, w_count: float = 1.0, w_height: float = 1.0) -> None:
        super().__init__()
        self.w_fit, self.w_count, self.w_height = w_fit, w_count, w_height
        self._seen: dict[tuple[float, float, float], None] = {}

    def reset(self, info: EpisodeInfo) -> None:
        super().reset(info)
        self._seen = {}

    def _typical(self, obs: Observation) -> np.ndarray:
        for box in (obs.box, *obs.lookahead):
            key = (box.length, box.width, box.height)
            self._seen.pop(key, None)
            self._seen[key] = None  # most recent last
            while len(self._seen) > TYPICAL_ITEMS:
                self._seen.pop(next(iter(self._seen)))
        return np.array([(cells_spanned(a), cells_spanned(b), h) for a, b, h in self._seen], dtype=np.float64)

    def act(self, obs: Observation) -> Action | None:
        ems = self.spaces(obs)
        typical = self._typical(obs)
        cands = ems_candidates(obs, ems, corners=4, dedupe=False)
        if len(cands) == 0:
            return None
        r = ems.rects[cands.ems]
        dx, dy = r[:, 2] - r[:, 0], r[:, 3] - r[:, 1]
        top = cands.z + cands.h
        height = obs.container.height
        fit = cands.lc * cands.wc / (dx * dy)
        # what remains of the space: (size x, size y, size z) of each slab, shape (C, 5, 3)
        slabs = np.stack(
            [
                np.stack([cands.x - r[:, 0], dy, height - ems.z0[cands.ems]], axis=1),
                np.stack([r[:, 2] - cands.x - cands.lc, dy, height - ems.z0[cands.ems]], axis=1),
                np.stack([dx, cands.y - r[:, 1], height - ems.z0[cands.ems]], axis=1),
                np.stack([dx, r[:, 3] - cands.y - cands.wc, height - ems.z0[cands.ems]], axis=1),
                np.stack([dx, dy, height - top], axis=1),
            ],
            axis=1,
        ).astype(np.float64)
        t = typical[None, None, :, :]  # (1, 1, T, 3)
        s = slabs[:, :, None, :]  # (C, 5, 1, 3)
        upright = (t[..., 0] <= s[..., 0]) & (t[..., 1] <= s[..., 1])
        turned = (t[..., 1] <= s[..., 0]) & (t[..., 0] <= s[..., 1])
        fits = (upright | turned) & (t[..., 2] <= s[..., 2] + 1e-6)  # (C, 5, T)
        still_fit = fits.any(axis=1).mean(axis=1)
        utility = self.w_fit * fit + self.w_count * still_fit - self.w_height * top / height
        order = np.lexsort((cands.orientation, cands.x, cands.x + cands.y, cands.z, -np.round(utility, 9)))
        return first_supported(obs, order, cands.x, cands.y, cands.orientation, cands.z)
