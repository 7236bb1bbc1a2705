"""SDFPack, signed-distance-field minimisation (Pan et al. 2023; RoboBPP paper, Algorithm "SDF Packing")."""

from __future__ import annotations

import numpy as np

from robobpp.core import Action, Observation
from robobpp.core.heightmap import cells_spanned
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import candidate_maps, first_supported_index
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


#: Candidates scored per round of the branch and bound.
CHUNK = 2048


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

    def _samples(self, c: Candidates) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = (np.arange(self.samples) + 0.5) / self.samples
        u = (np.arange(self.levels) + 0.5) / self.levels
        rows_x = c.x[:, None] + np.floor(s[None, :] * c.lc[:, None]).astype(np.int64)  # along the x extent
        rows_y = c.y[:, None] + np.floor(s[None, :] * c.wc[:, None]).astype(np.int64)  # along the y extent
        t = c.z[:, None] + u[None, :] * c.h[:, None]
        return rows_x, rows_y, t

    @property
    def _count(self) -> int:
        return 4 * self.samples * self.levels + self.samples * self.samples

    def bottom_cost(self, hm: np.ndarray, c: Candidates) -> np.ndarray:
        """The bottom face's share of :meth:`sdf_cost` (cheap: the gap under the box, one lookup per sample)."""
        rows_x, rows_y, _ = self._samples(c)
        under = hm[rows_x[:, :, None], rows_y[:, None, :]]  # (C, S, S) bottom samples
        return np.minimum(c.z[:, None, None] - under, self.tau).sum(axis=(1, 2)) / (self.tau * self._count)

    def sdf_cost(self, hm: np.ndarray, c: Candidates) -> np.ndarray:
        """Mean truncated distance / τ of every candidate's surface samples, in [0, 1]."""
        rows_x, rows_y, t = self._samples(c)
        tau = self.tau
        total = (
            _face_distance(hm, rows_y, c.x - 1, -1, t, tau, along_x=True).sum(axis=(1, 2))
            + _face_distance(hm, rows_y, c.x + c.lc, 1, t, tau, along_x=True).sum(axis=(1, 2))
            + _face_distance(hm, rows_x, c.y - 1, -1, t, tau, along_x=False).sum(axis=(1, 2))
            + _face_distance(hm, rows_x, c.y + c.wc, 1, t, tau, along_x=False).sum(axis=(1, 2))
        )
        return total / (tau * self._count) + self.bottom_cost(hm, c)

    def act(self, obs: Observation) -> Action | None:
        cands = every_position(obs)
        if len(cands) == 0:
            return None
        hm = obs.heightmap
        base = self.w_height * (cands.z + cands.h) / obs.container.height + self.w_rot * (
            cands.orientation != 0
        )
        # Branch and bound, exact: the side faces only add, so base + bottom is a lower bound of the cost.
        # Side faces are computed in bound order until the best supported cost so far beats every bound left.
        bound = base + self.bottom_cost(hm, cands)
        by_bound = np.argsort(bound, kind="stable")
        cost = np.full(len(cands), np.inf)
        best: Action | None = None
        best_cost = np.inf
        start = 0
        while start < len(by_bound) and bound[by_bound[start]] <= best_cost:
            chunk = by_bound[start : start + CHUNK]
            cost[chunk] = np.round(base[chunk] + self.sdf_cost(hm, cands.take(chunk)), 9)
            start += len(chunk)
            done = by_bound[:start]
            order = done[np.lexsort((cands.orientation[done], cands.x[done], cands.x[done] + cands.y[done],
                                     cands.z[done], cost[done]))]  # fmt: skip
            k = first_supported_index(obs, order, cands.x, cands.y, cands.orientation, cands.z)
            if k is not None:
                best = Action(float(cands.x[k]), float(cands.y[k]), int(cands.orientation[k]))
                best_cost = float(cost[k])
        return best
