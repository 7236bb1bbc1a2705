"""SDFPack, signed-distance-field minimisation (Pan et al. 2023; RoboBPP paper, Algorithm "SDF Packing")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.policies.candidates import first_supported
from robobpp.policies.ems import Candidates, EmsPolicy, ems_candidates


def _face_distance(
    hm: np.ndarray, rows: np.ndarray, cols0: np.ndarray, step: int, t: np.ndarray, tau: int, along_x: bool
) -> np.ndarray:
    """Truncated distance (cells) from sample points on one side face to the nearest solid along the
    face's outward normal: a heightmap column taller than the point, or the container wall.

    ``rows`` (C, S) index the face cells, ``cols0`` (C,) the first column outside the face, ``step`` ±1
    the outward direction, ``t`` (C, T) the sample heights. Returns (C, S, T) in [0, tau].
    """
    nx, ny = hm.shape
    limit = nx if along_x else ny
    reach = np.full(rows.shape, -np.inf)
    free = np.zeros((*rows.shape, t.shape[1]))
    for k in range(tau):
        col = cols0[:, None] + step * k
        wall = (col < 0) | (col >= limit)
        c = np.clip(col, 0, limit - 1)
        h = hm[c, rows] if along_x else hm[rows, c]
        reach = np.maximum(reach, np.where(wall, np.inf, h))
        free += reach[:, :, None] <= t[:, None, :]
    return free


class SDFPack(EmsPolicy):
    """SDF minimisation: over every EMS, orientation and bottom corner of the space, minimise

    ``cost = mean TSDF over the box's surface samples / τ + w_height · (z + h) / H + w_rot · [rotated]``

    where the TSDF of the packed scene (container walls, floor and heightmap) is evaluated on a grid of
    points of the box's bottom and four side faces and truncated at ``τ`` cm: a box that touches its
    neighbours everywhere scores 0, one in open space scores 1. Pan et al. minimise the SDF of the scene
    sampled on the object's surface plus a height term; the paper adds a rotation penalty.

    Choices where the paper is vague (docs/baselines.md): the scene is 2.5-D (the heightmap), so the distance
    is measured along each face's outward normal (an upper bound of the Euclidean distance); the top face is
    left out (it stays open for the next boxes); candidates are the EMS corners rather than every cell,
    since a distance-minimising placement always sits snug in some corner of a space.
    """

    name = "sdfpack"

    def __init__(
        self, tau: int = 6, samples: int = 8, levels: int = 4, w_height: float = 1.0, w_rot: float = 0.02
    ) -> None:
        super().__init__()
        self.tau, self.samples, self.levels = tau, samples, levels
        self.w_height, self.w_rot = w_height, w_rot

    def sdf_cost(self, hm: np.ndarray, c: Candidates) -> np.ndarray:
        """Mean truncated distance / τ of every candidate's surface samples, in [0, 1]."""
        s = (np.arange(self.samples) + 0.5) / self.samples
        u = (np.arange(self.levels) + 0.5) / self.levels
        rows_x = c.x[:, None] + np.floor(s[None, :] * c.lc[:, None]).astype(np.int64)  # along the x extent
        rows_y = c.y[:, None] + np.floor(s[None, :] * c.wc[:, None]).astype(np.int64)  # along the y extent
        t = c.z[:, None] + u[None, :] * c.h[:, None]
        tau = self.tau
        total = (
            _face_distance(hm, rows_y, c.x - 1, -1, t, tau, along_x=True).sum(axis=(1, 2))
            + _face_distance(hm, rows_y, c.x + c.lc, 1, t, tau, along_x=True).sum(axis=(1, 2))
            + _face_distance(hm, rows_x, c.y - 1, -1, t, tau, along_x=False).sum(axis=(1, 2))
            + _face_distance(hm, rows_x, c.y + c.wc, 1, t, tau, along_x=False).sum(axis=(1, 2))
        )
        under = hm[rows_x[:, :, None], rows_y[:, None, :]]  # (C, S, S) bottom samples
        total = total + np.minimum(c.z[:, None, None] - under, tau).sum(axis=(1, 2))
        count = 4 * self.samples * self.levels + self.samples * self.samples
        return total / (tau * count)

    def act(self, obs: Observation) -> Action | None:
        cands = ems_candidates(obs, self.spaces(obs), corners=4)
        if len(cands) == 0:
            return None
        cost = (
            self.sdf_cost(obs.heightmap, cands)
            + self.w_height * (cands.z + cands.h) / obs.container.height
            + self.w_rot * (cands.orientation != 0)
        )
        order = np.lexsort((cands.orientation, cands.x, cands.x + cands.y, cands.z, np.round(cost, 9)))
        return first_supported(obs, order, cands.x, cands.y, cands.orientation, cands.z)
