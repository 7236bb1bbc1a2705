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

Support (the reference's rule for a box that does not rest on the floor): the boxes whose tops are at the
resting height and overlap the footprint form a contact polygon (convex hull of the overlaps), shrunk by
10 % towards its centre; the box's centre must lie strictly inside it. The reference then propagates the
box's weight down through the stack; that second part is not done here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robobpp.core import Observation, Placement, drop_height_map
from robobpp.core.feasibility import TOLERANCE_CM

INTERNAL_HOLDER = 80
LEAF_HOLDER = 50
#: Smallest side of a space worth keeping, cm (the reference uses the smallest item side of its item set).
MIN_SPACE = 1.0
#: Two tops count as the same level within this distance, cm (physics settles boxes by fractions of a mm).
LEVEL_TOLERANCE = 0.5
#: The reference shrinks the contact polygon by this fraction towards its centre.
SHRINK = 0.1


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
    return spaces[~inside.any(axis=1)]


def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull, counter-clockwise, of 2-D points (Andrew's monotone chain)."""
    pts = sorted(set(map(tuple, points.tolist())))
    if len(pts) < 3:
        return np.array(pts)

    def half(seq: list) -> list:
        out: list = []
        for p in seq:
            while len(out) >= 2 and (
                (out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])
                <= 0
            ):
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def supported(x0: float, y0: float, sx: float, sy: float, z: float, tops: np.ndarray) -> bool:
    """The reference's support rule for a box resting at ``z`` (see the module docstring).

    ``tops`` is (n, 5): x0, y0, x1, y1, top of the placed boxes (whole-cell footprints).
    """
    if z <= TOLERANCE_CM:
        return True
    level = tops[np.abs(tops[:, 4] - z) <= LEVEL_TOLERANCE]
    lo = np.maximum(level[:, :2], (x0, y0))
    hi = np.minimum(level[:, 2:4], (x0 + sx, y0 + sy))
    ok = np.all(hi > lo, axis=1)
    if not ok.any():
        return False
    lo, hi = lo[ok], hi[ok]
    corners = np.concatenate([lo, hi, np.c_[lo[:, 0], hi[:, 1]], np.c_[hi[:, 0], lo[:, 1]]])
    hull = _hull(corners)
    if len(hull) < 3:
        return False
    hull = hull - SHRINK * (hull - hull.mean(axis=0))
    centre = np.array([x0 + sx / 2, y0 + sy / 2])
    edge = np.roll(hull, -1, axis=0) - hull
    to_point = centre - hull
    return bool(np.all(edge[:, 0] * to_point[:, 1] - edge[:, 1] * to_point[:, 0] > 0))


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
    placed = obs.placed[-INTERNAL_HOLDER:]
    internal = np.zeros((INTERNAL_HOLDER, 6))
    internal_valid = np.zeros(INTERNAL_HOLDER, bool)
    internal_valid[0] = True  # the reference marks the first (all-zero) node valid before any box is placed
    extents = np.array([box_extent(p) for p in placed]).reshape(-1, 6)
    internal[: len(extents)] = extents
    internal_valid[: len(extents)] = True

    candidates: dict[tuple[float, float, float, int], int] = {}  # (x0, y0, z_space, orientation) -> order
    heights: dict[int, tuple[int, int, float, np.ndarray]] = {}
    for orientation in obs.orientations:
        length, width, height = obs.box.dims(orientation)
        sx, sy = cells(length), cells(width)
        if heights and sx == sy:
            continue  # a square footprint: the turned box is the same placement
        if sx > container.length + TOLERANCE_CM or sy > container.width + TOLERANCE_CM:
            continue
        heights[orientation] = (sx, sy, height, drop_height_map(obs.heightmap, length, width))
        fits = np.all(spaces[:, 3:] - spaces[:, :3] >= (sx, sy, height - 1e-9), axis=1)
        for x1, y1, z1, x2, y2, _ in spaces[fits]:
            for x, y in ((x1, y1), (x2 - sx, y1), (x1, y2 - sy), (x2 - sx, y2 - sy)):
                candidates.setdefault((x, y, z1, orientation), len(candidates))

    order = list(candidates)
    rng.shuffle(order)  # type: ignore[arg-type]
    tops = extents[:, [0, 1, 3, 4, 5]]
    leaves = np.zeros((LEAF_HOLDER, 8))
    actions: list[tuple[int, int, int]] = []
    for x, y, z_space, orientation in order:
        sx, sy, height, z_map = heights[orientation]
        ix, iy = int(x), int(y)
        if not (0 <= ix < z_map.shape[0] and 0 <= iy < z_map.shape[1]):
            continue
        z = float(z_map[ix, iy])
        if z + height > container.height + TOLERANCE_CM or not supported(ix, iy, sx, sy, z, tops):
            continue
        leaves[len(actions)] = (ix, iy, z_space, ix + sx, iy + sy, container.height, 0, 0)
        actions.append((ix, iy, orientation))
        if len(actions) == LEAF_HOLDER:
            break
    leaf_valid = np.zeros(LEAF_HOLDER, bool)
    leaf_valid[: len(actions)] = True
    b = obs.box
    next_item = np.array([1.0, 0.0, 0.0, *sorted((cells(b.length), cells(b.width), b.height))])
    return Nodes(internal, internal_valid, leaves, leaf_valid, next_item, actions)
