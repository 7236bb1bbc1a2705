"""SDFPack, signed-distance-field minimisation (Pan et al. 2023; RoboBPP paper, Algorithm "SDF Packing")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.core.heightmap import cells_spanned
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import candidate_maps, first_supported
from robobpp.policies.ems import Candidates


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


def every_position(obs: Observation) -> Candidates:
    """Every integer position and orientation where the box fits the container (bounds and height)."""
    parts = []
    for cand in candidate_maps(obs):
        px, py = np.nonzero(cand.fits)
        n = len(px)
        lc, wc = cells_spanned(cand.length), cells_spanned(cand.width)
        parts.append(
            (px, py, np.full(n, cand.orientation), cand.z[px, py], np.zeros(n, np.int64),
             np.full(n, lc), np.full(n, wc), np.full(n, cand.height))
        )  # fmt: skip
    if not parts:
        empty = np.zeros(0, dtype=np.int64)
        return Candidates(empty, empty, empty, np.zeros(0), empty, empty, empty, np.zeros(0))
    return Candidates(*(np.concatenate(c) for c in zip(*parts, strict=True)))


class SDFPack(BasePolicy):
    """SDF minimisation: over every 1 cm position and orientation (the paper's pseudocode), minimise

    ``cost = mean TSDF over the box's surface samples / τ + w_height · (z + h) / H + w_rot · [rotated]``

    where the TSDF of the packed scene (container walls, floor and heightmap) is evaluated on a grid of
    points of the box's bottom and four side faces and truncated at ``τ`` cm: a box that touches its
    neighbours everywhere scores 0, one in open space scores 1. Pan et al. minimise the SDF of the scene
    sampled on the object's surface plus a height term; the paper adds a rotation penalty.

    Choices where the paper is vague (docs/baselines.md): the scene is 2.5-D (the heightmap), so the distance
    is measured along each face's outward normal (an upper bound of the Euclidean distance); the top face is
    left out (it stays open for the next boxes). Ties: lower z, then back-left, then orientation 0. Not in the
    reference code (its heuristics file has no SDFPack); the paper's pseudocode is followed.
    """

    name = "sdfpack"

    def __init__(
        self, tau: int = 6, samples: int = 8, levels: int = 4, w_height: float = 1.0, w_rot: float = 0.02
    ) -> None:
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
        cands = every_position(obs)
        if len(cands) == 0:
            return None
        cost = (
            self.sdf_cost(obs.heightmap, cands)
            + self.w_height * (cands.z + cands.h) / obs.container.height
            + self.w_rot * (cands.orientation != 0)
        )
        order = np.lexsort((cands.orientation, cands.x, cands.x + cands.y, cands.z, np.round(cost, 9)))
        return first_supported(obs, order, cands.x, cands.y, cands.orientation, cands.z)
