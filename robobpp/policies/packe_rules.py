"""PackE-rules: PackE's candidate generators (Yang et al. 2021) with a fixed rule in place of its RL agent."""

from __future__ import annotations

import math

import numpy as np

from robobpp.core import Action, Observation
from robobpp.core.heightmap import cells_spanned
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import candidate_maps
from robobpp.policies.hm import window_sums


class PackERules(BasePolicy):
    """PackE's heuristic candidates, for each orientation, on the 1 cm grid (RoboBPP paper, Algorithm "PackE"):

    1. first fit — the first feasible position in row-major order (x, then y);
    2. floor building — the feasible position that rests lowest;
    3. column building — the feasible position that rests highest;
    4. extreme points — for every placed box, its right corner ``(x + l, y)`` and front corner ``(x, y + w)``,
       plus the container origin;

    every candidate must be feasible (inside, below the top; no support test, like the paper's heuristics). Not
    one of the paper's baselines; kept as a stronger rule-based reference point. PackE lets a learned agent choose among the candidates;
    the fixed rule here takes the lowest resulting top ``z + h``, then the least volume trapped under the
    box, then the smallest ``x + y``, then orientation 0.
    """

    name = "packe-rules"

    def act(self, obs: Observation) -> Action | None:
        picks: list[tuple[float, float, int, int, int, int]] = []  # (top, gap, x + y, orientation, x, y)
        for cand in candidate_maps(obs):
            feasible = cand.fits
            if not feasible.any():
                continue
            nx, ny = cand.z.shape
            z = cand.z
            flat = np.flatnonzero(feasible)
            zf = z.flat[flat]
            chosen = {int(flat[0]), int(flat[np.argmin(zf)]), int(flat[np.argmax(zf)])}
            points = (
                [(0, 0)]
                + [(math.ceil(p.x + p.length - 1e-6), max(0, math.floor(p.y + 1e-6))) for p in obs.placed]
                + [(max(0, math.floor(p.x + 1e-6)), math.ceil(p.y + p.width - 1e-6)) for p in obs.placed]
            )
            for x, y in points:
                if 0 <= x < nx and 0 <= y < ny and feasible[x, y]:
                    chosen.add(x * ny + y)
            idx = np.fromiter(chosen, dtype=np.int64)
            xs, ys = np.divmod(idx, ny)
            lc, wc = cells_spanned(cand.length), cells_spanned(cand.width)
            zs = z[xs, ys]
            gap = lc * wc * zs - window_sums(obs.heightmap, lc, wc)[xs, ys]
            for x, y, zz, g in zip(xs.tolist(), ys.tolist(), zs.tolist(), gap.tolist(), strict=True):
                picks.append((zz + cand.height, round(g, 6), x + y, cand.orientation, x, y))
        if not picks:
            return None
        top, gap, _, orientation, x, y = min(picks)
        return Action(float(x), float(y), orientation)
