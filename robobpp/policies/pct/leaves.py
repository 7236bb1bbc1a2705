"""PCT's tree nodes for one decision: internal nodes (placed boxes), leaf nodes (candidate placements), next item.

The facts follow the authors' discrete environment (``pct_envs/PctDiscrete0`` in the PCT repository and in
packsim), with the Leaf Node Expansion Scheme "EMS" the weights were trained with:

* **Empty maximal spaces** are kept item by item: each placed box (its footprint on whole cells, its
  bottom and top) cuts every space it overlaps into up to five slabs — beside it on the four sides and
  above it; none below — and a slab thinner than ``MIN_SPACE`` cm in any axis, or contained in another
  space, is dropped. Unlike ``robobpp/policies/ems.py`` (spaces of the heightmap), these spaces may
  reach over a void; the network was trained on them, so we keep them.
* **Leaves**: for every space and both yaw orientations of the box (integer footprint, ceil of the length
  and width), the four floor corners of the space where the box fits inside it. Each is then checked like
  a drop onto the heightmap: inside the container, top ≤ container height, and supported (below).
  Candidates are shuffled (seeded) before the first 50 feasible ones are kept, as the reference shuffles.
* **Features**, all later scaled by 1 / the longest container side: internal ``[x0, y0, z0, x1, y1, z1]``
  of each placed box (before the first box, one all-zero node is valid, as in the reference); leaf
  ``[x0, y0, z_space, x1, y1, H, 0, 0]`` (the space's floor, not the resting height, and the container
  height H, as the reference writes them); next item ``[density = 1, 0, 0, its three sides ascending]``.

Support: the reference's rule as the reference's PCT environment applies it to its leaves
(:func:`robobpp.policies.candidates.support_model`): in the physical settings a leaf must pass the recursive
centre-of-mass test; in Math Pack, as in the reference's Math Pack, there is no such check. (The paper's heuristics
never apply it, and no setting enforces it.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robobpp.core import Observation, Placement, drop_height_map
from robobpp.core.feasibility import TOLERANCE_CM
from robobpp.policies.candidates import support_model

INTERNAL_HOLDER = 80
LEAF_HOLDER = 50
#: Smallest side of a space worth keeping, cm (the reference uses the smallest item side of its item set).
MIN_SPACE = 1.0
#: Candidates whose support is tested together (about what yields 50 leaves in one or two batches).
_BATCH = 96


def cells(length: float) -> int:
    """Whole 1 cm cells a side covers (the reference ceils lengths and widths to its grid)."""
    return math.ceil(length - 1e-9)


def box_extent(p: Placement) -> tuple[float, float, float, float, float, float]:
    """A placed box as whole-cell footprint and real heights: (x0, y0, z0, x1, y1, z1)."""
    x0, y0 = round(p.x), round(p.y)
    return (x0, y0, p.z, x0 + cells(p.length), y0 + cells(p.width), p.z + p.height)


class SpaceTracker:
    """Empty maximal spaces of one container, updated box by box; rebuilt when the placed boxes changed."""

    def __init__(self, length: float, width: float, height: float) -> None:
        self.bounds = np.array([0.0, 0.0, 0.0, cells(length), cells(width), height])
        self.reset()

    def reset(self) -> None:
        self.spaces = self.bounds[None, :].copy()
        self.applied: list[tuple[float, ...]] = []

    def sync(self, placed: tuple[Placement, ...]) -> np.ndarray:
        """Spaces for these placed boxes: incremental when they extend the ones applied, else from scratch."""
        extents = [box_extent(p) for p in placed]
        keys = [tuple(round(v, 1) for v in e) for e in extents]
        if keys[: len(self.applied)] != self.applied:
            self.reset()  # a box moved (physics) or a new episode: start over
        for extent, key in zip(extents[len(self.applied) :], keys[len(self.applied) :], strict=True):
            self.cut(np.array(extent))
            self.applied.append(key)
        return self.spaces

    def cut(self, item: np.ndarray) -> None:
        s = self.spaces
        lo = np.maximum(s[:, :3], item[:3])
        hi = np.minimum(s[:, 3:], item[3:])
        hit = np.all(hi > lo, axis=1)
        if not hit.any():
            return
        pieces = []
        for space, a, b in zip(s[hit], lo[hit], hi[hit], strict=True):
            x1, y1, z1, x2, y2, z2 = space
            pieces += [
                (x1, y1, z1, a[0], y2, z2),
                (b[0], y1, z1, x2, y2, z2),
                (x1, y1, z1, x2, a[1], z2),
                (x1, b[1], z1, x2, y2, z2),
                (x1, y1, b[2], x2, y2, z2),
            ]
        new = np.array(pieces)
        new = new[np.all(new[:, 3:] - new[:, :3] >= MIN_SPACE, axis=1)]
        self.spaces = _maximal(np.concatenate([s[~hit], new]))


def _maximal(spaces: np.ndarray) -> np.ndarray:
    """Drop duplicates and every space contained in another (the reference drops contained spaces)."""
    spaces = np.unique(spaces, axis=0)
    lo, hi = spaces[:, :3], spaces[:, 3:]
    inside = np.all(lo[:, None] >= lo[None], axis=2) & np.all(hi[:, None] <= hi[None], axis=2)
    np.fill_diagonal(inside, False)
    maximal: np.ndarray = spaces[~inside.any(axis=1)]
    return maximal


@dataclass(frozen=True, slots=True)
class Leaves:
    """Feasible leaf placements for one box, in the reference's shuffled order: the box's corner ``(x, y)``
    (cells), its orientation, the floor of the space it was found in, its footprint (whole cells) and height, and
    the height it rests at when dropped there."""

    xs: np.ndarray  # (n,) int
    ys: np.ndarray  # (n,) int
    orientations: np.ndarray  # (n,) int
    z_space: np.ndarray  # (n,) float: the space's floor (what the reference's features show)
    size: np.ndarray  # (n, 3): footprint cells (x, y) and the box's height
    z_rest: np.ndarray  # (n,) float: the drop height on the heightmap

    def __len__(self) -> int:
        return len(self.xs)

    def actions(self) -> list[tuple[int, int, int]]:
        return [(int(x), int(y), int(o)) for x, y, o in zip(self.xs, self.ys, self.orientations, strict=True)]


def feasible_leaves(
    obs: Observation, spaces: np.ndarray, rng: np.random.Generator, limit: int = LEAF_HOLDER
) -> Leaves:
    """The first ``limit`` feasible leaves for the observation's box, given the current empty maximal spaces.

    Every floor corner of every space the box fits, for both yaw orientations, shuffled by ``rng`` (as the
    reference shuffles), each checked as a drop onto the heightmap (inside, below the container's top) and, in
    the physical settings, against the support rule the reference's PCT applies."""
    container = obs.container
    corners = []  # (x0, y0, z_space, orientation) of the box in each floor corner of each space it fits
    heights: dict[int, tuple[int, int, float, np.ndarray]] = {}
    for orientation in obs.orientations:
        length, width, height = obs.box.dims(orientation)
        sx, sy = cells(length), cells(width)
        if heights and sx == sy:
            continue  # a square footprint: the turned box is the same placement
        if sx > container.length + TOLERANCE_CM or sy > container.width + TOLERANCE_CM:
            continue
        heights[orientation] = (sx, sy, height, drop_height_map(obs.heightmap, length, width))
        fit = spaces[np.all(spaces[:, 3:] - spaces[:, :3] >= (sx, sy, height - 1e-9), axis=1)]
        for x, y in (
            (fit[:, 0], fit[:, 1]),
            (fit[:, 3] - sx, fit[:, 1]),
            (fit[:, 0], fit[:, 4] - sy),
            (fit[:, 3] - sx, fit[:, 4] - sy),
        ):
            corners.append(np.stack([x, y, fit[:, 2], np.full(len(fit), orientation)], axis=1))

    # Check every candidate as a drop at once (in the reference's shuffled order), then keep the first ``limit``.
    order = np.unique(np.concatenate(corners), axis=0) if corners else np.zeros((0, 4))
    rng.shuffle(order)
    xs, ys, orient = order[:, 0].astype(int), order[:, 1].astype(int), order[:, 3].astype(int)
    size = np.array([heights[o][:3] for o in orient]).reshape(-1, 3)
    z = np.full(len(order), np.inf)
    for o, (_, _, _, z_map) in heights.items():
        pick = (orient == o) & (xs >= 0) & (ys >= 0) & (xs < z_map.shape[0]) & (ys < z_map.shape[1])
        z[pick] = z_map[xs[pick], ys[pick]]
    fits = z + size[:, 2] <= container.height + TOLERANCE_CM
    # The support rule as the reference's PCT applies it (none in Math Pack), tested in the shuffled order in batches
    # (the model tests a batch of positions of one orientation together) until ``limit`` leaves are found.
    support = support_model(obs)
    candidates, accepted = np.flatnonzero(fits), 0
    fits[:] = False
    for start in range(0, len(candidates), _BATCH):
        batch = candidates[start : start + _BATCH]
        for o, (_, _, height, z_map) in heights.items():
            pick = batch[orient[batch] == o]
            if pick.size == 0:
                continue
            wanted = np.zeros(z_map.shape, bool)
            wanted[xs[pick], ys[pick]] = True
            length, width, _ = obs.box.dims(o)
            fits[pick] = support.mask(z_map, length, width, height, wanted)[xs[pick], ys[pick]]
        accepted += int(fits[batch].sum())
        if accepted >= limit:
            break
    chosen = np.flatnonzero(fits)[:limit]
    return Leaves(xs[chosen], ys[chosen], orient[chosen], order[chosen, 2], size[chosen], z[chosen])


@dataclass(frozen=True, slots=True)
class Nodes:
    """The network's inputs for one decision and what each leaf means as an action."""

    internal: np.ndarray  # (INTERNAL_HOLDER, 6)
    internal_valid: np.ndarray  # (INTERNAL_HOLDER,) bool
    leaves: np.ndarray  # (LEAF_HOLDER, 8)
    leaf_valid: np.ndarray  # (LEAF_HOLDER,) bool
    next_item: np.ndarray  # (6,)
    actions: list[tuple[int, int, int]]  # (x, y, orientation) of each valid leaf, in leaf order


def build_nodes(obs: Observation, spaces: np.ndarray, rng: np.random.Generator) -> Nodes:
    """The PCT nodes for the observation's box, given the current empty maximal spaces."""
    container = obs.container
    extents = np.array([box_extent(p) for p in obs.placed]).reshape(-1, 6)
    internal = np.zeros((INTERNAL_HOLDER, 6))
    internal_valid = np.zeros(INTERNAL_HOLDER, bool)
    internal_valid[0] = True  # the reference marks the first (all-zero) node valid before any box is placed
    recent = extents[-INTERNAL_HOLDER:]  # the reference holds 80 boxes; a longer episode shows the latest
    internal[: len(recent)] = recent
    internal_valid[: len(recent)] = True

    found = feasible_leaves(obs, spaces, rng, LEAF_HOLDER)
    n = len(found)
    leaves = np.zeros((LEAF_HOLDER, 8))
    leaves[:n] = np.column_stack(
        [
            found.xs,
            found.ys,
            found.z_space,
            found.xs + found.size[:, 0],
            found.ys + found.size[:, 1],
            np.full(n, container.height),
            np.zeros((n, 2)),
        ]
    )
    leaf_valid = np.zeros(LEAF_HOLDER, bool)
    leaf_valid[:n] = True
    b = obs.box
    next_item = np.array([1.0, 0.0, 0.0, *sorted((cells(b.length), cells(b.width), b.height))])
    return Nodes(internal, internal_valid, leaves, leaf_valid, next_item, found.actions())
