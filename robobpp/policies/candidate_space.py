"""The candidate action space: at most K feasible placements per box, each with its features.

The paper's learned methods (PCT and its successors) do not act on every cell of the container: they choose among
a short list of candidate placements, the leaf nodes of the packing configuration tree. This is that list, built
as the reference's PCT builds its leaves (:func:`robobpp.policies.pct.leaves.feasible_leaves`): the floor corners
of the empty maximal spaces where the box fits, both yaw orientations, shuffled (seeded by the episode, so the env
and a served policy see the same list), checked as drops onto the heightmap and, in the physical settings, against
the support rule the reference's PCT applies; the first K are kept (the reference keeps 50: the default).

Each candidate is a row of :data:`FEATURES`, scaled to [0, 1] by the container's sides (x by its length, y by
its width, heights by its height):

* ``valid``: 1 for a candidate, 0 for a padding row (the list is zero-padded to K);
* ``x0, y0, x1, y1``: the box's footprint; ``z``: the height it rests at; ``top``: ``z`` + its height;
* ``gap``: the mean empty height left under the box (``z`` minus the mean of the heightmap under its footprint):
  space the placement wastes;
* ``support``: the share of the footprint's cells the box rests on (within the contact tolerance);
* ``z_space``: the floor of the empty space the candidate came from (what the reference's own leaf features
  show): at least ``z``, above it where the space reaches over lower terrain.

:class:`Candidates` maps an index back to the placement (:meth:`Candidates.action`). The Gym env's
``actions="candidates"`` (:mod:`robobpp.env`) uses it, and so can a policy acting on an :class:`Observation`
(the training example serves its agent that way).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from robobpp.core import Action, ContainerSpec, Observation
from robobpp.core.feasibility import TOLERANCE_CM
from robobpp.policies.pct.leaves import LEAF_HOLDER, SpaceTracker, feasible_leaves

#: The columns of a candidate's feature row (module docstring).
FEATURES = ("valid", "x0", "y0", "z", "x1", "y1", "top", "gap", "support", "z_space")
#: Candidates kept per box by default: the reference's PCT keeps 50 leaves.
DEFAULT_CANDIDATES = LEAF_HOLDER


@dataclass(frozen=True, slots=True)
class Candidates:
    """One box's candidate list, padded to K rows: placements ``(x, y, orientation)``, features, mask."""

    placements: np.ndarray  # (K, 3) int64; padding rows are zeros
    features: np.ndarray  # (K, len(FEATURES)) float32
    mask: np.ndarray  # (K,) bool: which rows are candidates

    def action(self, index: int) -> Action | None:
        """The placement of candidate ``index``; None for a padding row or an index outside the list."""
        if not 0 <= index < len(self.mask) or not self.mask[index]:
            return None
        x, y, orientation = (int(v) for v in self.placements[index])
        return Action(float(x), float(y), orientation)


class CandidateSpace:
    """Builds each box's :class:`Candidates`, keeping the empty maximal spaces between the boxes of an episode.

    Call :meth:`reset` at the start of every episode: the shuffle is seeded by ``seed`` and the episode id, so the
    same episode gives the same lists wherever it is played (in the env, or served behind the protocol)."""

    def __init__(self, limit: int = DEFAULT_CANDIDATES, seed: int = 0) -> None:
        if isinstance(limit, bool) or not isinstance(limit, int) or limit < 1:
            raise ValueError(f"the candidate count must be an integer >= 1, got {limit!r}")
        self.limit, self.seed = limit, seed
        self._tracker: SpaceTracker | None = None
        self._rng = np.random.default_rng(seed)

    def reset(self, container: ContainerSpec, episode_id: str) -> None:
        self._tracker = SpaceTracker(container.length, container.width, container.height)
        self._rng = np.random.default_rng([self.seed, zlib.crc32(episode_id.encode())])

    def __call__(self, obs: Observation) -> Candidates:
        c = obs.container
        if self._tracker is None:  # used without reset: start from this container
            self._tracker = SpaceTracker(c.length, c.width, c.height)
        leaves = feasible_leaves(obs, self._tracker.sync(obs.placed), self._rng, self.limit)
        n = len(leaves)
        placements = np.zeros((self.limit, 3), np.int64)
        placements[:n] = np.column_stack([leaves.xs, leaves.ys, leaves.orientations])
        features = np.zeros((self.limit, len(FEATURES)), np.float32)
        if n:
            sx, sy, height = leaves.size[:, 0].astype(int), leaves.size[:, 1].astype(int), leaves.size[:, 2]
            under_mean, resting = _footprint_figures(
                obs.heightmap, leaves.xs, leaves.ys, sx, sy, leaves.z_rest
            )
            features[:n] = np.column_stack(
                [
                    np.ones(n),
                    leaves.xs / c.length,
                    leaves.ys / c.width,
                    leaves.z_rest / c.height,
                    np.minimum(leaves.xs + sx, c.length) / c.length,
                    np.minimum(leaves.ys + sy, c.width) / c.width,
                    np.minimum(leaves.z_rest + height, c.height) / c.height,
                    np.clip(leaves.z_rest - under_mean, 0.0, c.height) / c.height,
                    resting,
                    np.clip(leaves.z_space, 0.0, c.height) / c.height,
                ]
            )
        mask = np.zeros(self.limit, bool)
        mask[:n] = True
        return Candidates(placements, features, mask)


def _footprint_figures(
    heightmap: np.ndarray, xs: np.ndarray, ys: np.ndarray, sx: np.ndarray, sy: np.ndarray, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per candidate: the mean heightmap under its footprint (a summed-area table: every mean in one pass), and
    the share of those cells it rests on (within the contact tolerance of its resting height)."""
    nx, ny = heightmap.shape
    x1, y1 = np.minimum(xs + sx, nx), np.minimum(ys + sy, ny)
    table = np.zeros((nx + 1, ny + 1))
    table[1:, 1:] = heightmap.cumsum(0).cumsum(1)
    sums = table[x1, y1] - table[xs, y1] - table[x1, ys] + table[xs, ys]
    cells = (x1 - xs) * (y1 - ys)
    resting = np.array(
        [
            np.count_nonzero(heightmap[x0:xe, y0:ye] >= zi - TOLERANCE_CM)
            for x0, y0, xe, ye, zi in zip(xs, ys, x1, y1, z, strict=True)
        ]
    )
    return sums / cells, resting / cells
