"""SDFPack, the RoboBPP paper's box version of SDF minimisation (Pan et al. 2023; Algorithm "SDF Packing").

The rule is the reference's own box implementation (packsim's packer module, function ``sdf_pack_regular``,
which its packer calls for method ``SDFPack``), read for its facts; docs/baselines.md states it and what its
distance term really measures.
"""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.core.heightmap import cells_spanned
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import candidate_maps, first_placement

#: The reference searches every second centimetre along x and y (its loops step by 2 from 0).
STEP = 2
#: Sample points inside the box every 5 cm along each axis, from its min corner.
SAMPLE = 5
#: Weight of the resting height: the reference adds ``posZ · block_unit`` with packsim's block unit 0.01.
Z_WEIGHT = 0.01
#: The point distances are measured from (cm): the container's origin corner (experiments move it to where the
#: reference's world-frame scene points lie: ``bench/paper_table.py --sdfpack-corner``).
CORNER = (0.0, 0.0, 0.0)
#: Distances summed per batch (bounds the memory of one evaluation).
_BATCH = 1 << 22


def sample_offsets(length: float, width: float, height: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets of the sample points from the box's min corner: 0, 5, 10, … below each (whole-cell) side."""
    return (
        np.arange(0, cells_spanned(length), SAMPLE, dtype=np.float64),
        np.arange(0, cells_spanned(width), SAMPLE, dtype=np.float64),
        np.arange(0, height, SAMPLE, dtype=np.float64),
    )


def distance_sum(
    xs: np.ndarray, ys: np.ndarray, zs: np.ndarray, offsets: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> np.ndarray:
    """For each candidate min corner (xs[k], ys[k], zs[k]) (cm), the sum over the box's sample points of
    their distance to the container's origin corner — what the reference's distance term measures (its
    scene points are in metres, its sample points in centimetres; docs/baselines.md)."""
    ox, oy, oz = (o - c for o, c in zip(offsets, CORNER, strict=True))
    n = len(xs)
    per = max(1, len(ox) * len(oy) * len(oz))
    out = np.empty(n)
    step = max(1, _BATCH // per)
    for s in range(0, n, step):
        e = min(n, s + step)
        a = (xs[s:e, None] + ox[None, :]) ** 2  # (C, I)
        b = (ys[s:e, None] + oy[None, :]) ** 2  # (C, J)
        c = (zs[s:e, None] + oz[None, :]) ** 2  # (C, K)
        d = np.sqrt(a[:, :, None, None] + b[:, None, :, None] + c[:, None, None, :])
        out[s:e] = d.sum(axis=(1, 2, 3))
    return out


class SDFPack(BasePolicy):
    """The reference's SDFPack for boxes. For each orientation (0, then 1) and each position on a 2 cm grid
    (``x = 0, 2, 4, … ≤ L − l``, ``y = 0, 2, … ≤ W − w``, whole-cell footprint) where the box, dropped, stays
    inside the container, minimise

    ``score = Σ_points d(p) + 0.01 · z + rot``

    over the sample points ``p = (x + 5i, y + 5j, z + 5k)`` inside the box (every 5 cm from its min corner),
    ``z`` the resting height and ``rot = 1 − (volume / bounding volume)^(1/3)``, which is 0 for a box.
    ``d(p)`` is meant as the distance to the packed scene (the reference's "TSDF": nearest of the
    heightmap's top points and the walls' and floor's projections of p); as the reference computes it — p in
    centimetres, the scene points in metres in its world frame, all within 4.4 units of the origin — it
    is the distance from p to the container's origin corner, which is what we compute (docs/baselines.md).

    Ties go to the first in the reference's loop order (orientation, then x, then y). No support test, in any
    setting, as the reference's.
    """

    name = "sdfpack"

    def distances(
        self,
        obs: Observation,
        xs: np.ndarray,
        ys: np.ndarray,
        zs: np.ndarray,
        offsets: tuple[np.ndarray, np.ndarray, np.ndarray],
    ) -> np.ndarray:
        """The distance term of every candidate (experiments replace it: ``bench/paper_table.py``)."""
        return distance_sum(xs, ys, zs, offsets)

    def act(self, obs: Observation) -> Action | None:
        parts = []
        for cand in candidate_maps(obs):
            nx, ny = cand.z.shape
            gx, gy = np.meshgrid(np.arange(0, nx, STEP), np.arange(0, ny, STEP), indexing="ij")
            keep = cand.fits[gx, gy]
            px, py = gx[keep], gy[keep]
            if px.size == 0:
                continue
            pz = cand.z[px, py].astype(np.float64)
            offsets = sample_offsets(cand.length, cand.width, cand.height)
            score = (
                self.distances(obs, px.astype(np.float64), py.astype(np.float64), pz, offsets) + Z_WEIGHT * pz
            )
            parts.append((px, py, np.full(px.size, cand.orientation), pz, np.round(score, 9)))
        if not parts:
            return None
        xs, ys, orient, zs, score = (np.concatenate(c) for c in zip(*parts, strict=True))
        ranked = np.lexsort((ys, xs, orient, score))
        return first_placement(ranked, xs, ys, orient)
