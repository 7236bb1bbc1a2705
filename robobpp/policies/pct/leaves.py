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


def _hull(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Convex hull, counter-clockwise, of 2-D points (Andrew's monotone chain)."""
    pts = sorted(set(points))

    def half(seq: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for p in seq:
            while len(out) >= 2 and (
                (out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])
                <= 0
            ):
                out.pop()
            out.append(p)
        return out

    return half(pts)[:-1] + half(pts[::-1])[:-1]


def _inside_shrunk_hull(contacts: np.ndarray, cx: float, cy: float) -> bool:
    """Whether (cx, cy) lies strictly inside the hull of the contact rectangles shrunk by ``SHRINK``."""
    if (
        len(contacts) == 1
    ):  # one rectangle: its hull's vertex mean is its centre, shrinking keeps it a rectangle
        x0, y0, x1, y1 = contacts[0]
        half_x, half_y = (1 - SHRINK) * (x1 - x0) / 2, (1 - SHRINK) * (y1 - y0) / 2
        return abs(cx - (x0 + x1) / 2) < half_x and abs(cy - (y0 + y1) / 2) < half_y
    corners = [(x, y) for x0, y0, x1, y1 in contacts.tolist() for x in (x0, x1) for y in (y0, y1)]
    hull = np.array(_hull(corners))
    hull = hull - SHRINK * (hull - hull.mean(axis=0))
    edge = np.roll(hull, -1, axis=0) - hull
    to_point = np.array([cx, cy]) - hull
    return bool(np.all(edge[:, 0] * to_point[:, 1] - edge[:, 1] * to_point[:, 0] > 0))


def _contacts(
    x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray, z: np.ndarray, tops: np.ndarray
):
    """For each footprint resting at ``z``: its overlap rectangles with the boxes whose tops are at ``z``.

    Returns (rects (n, b, 4), touching (n, b) bool). ``tops`` is (b, 5): x0, y0, x1, y1, top.
    """
    level = np.abs(tops[None, :, 4] - z[:, None]) <= LEVEL_TOLERANCE
    rects = np.stack(
        [
            np.maximum(tops[None, :, 0], x0[:, None]),
            np.maximum(tops[None, :, 1], y0[:, None]),
            np.minimum(tops[None, :, 2], x1[:, None]),
            np.minimum(tops[None, :, 3], y1[:, None]),
        ],
        axis=2,
    )
    touching = level & (rects[..., 2] > rects[..., 0]) & (rects[..., 3] > rects[..., 1])
    return rects, touching


def supported(x0: float, y0: float, sx: float, sy: float, z: float, tops: np.ndarray) -> bool:
    """The reference's support rule for one box resting at ``z`` (see the module docstring).

    ``tops`` is (b, 5): x0, y0, x1, y1, top of the placed boxes (whole-cell footprints).
    """
    if z <= TOLERANCE_CM:
        return True
    one = np.array
    rects, touching = _contacts(one([x0]), one([y0]), one([x0 + sx]), one([y0 + sy]), one([z]), tops)
    return bool(touching[0].any()) and _inside_shrunk_hull(rects[0, touching[0]], x0 + sx / 2, y0 + sy / 2)


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
        for x, y in ((fit[:, 0], fit[:, 1]), (fit[:, 3] - sx, fit[:, 1]), (fit[:, 0], fit[:, 4] - sy),
                     (fit[:, 3] - sx, fit[:, 4] - sy)):  # fmt: skip
            corners.append(np.stack([x, y, fit[:, 2], np.full(len(fit), orientation)], axis=1))

    # Check every candidate as a drop at once (in the reference's shuffled order), then keep the first 50.
    order = np.unique(np.concatenate(corners), axis=0) if corners else np.zeros((0, 4))
    rng.shuffle(order)
    xs, ys, orient = order[:, 0].astype(int), order[:, 1].astype(int), order[:, 3].astype(int)
    size = np.array([heights[o][:3] for o in orient]).reshape(-1, 3)
    z = np.full(len(order), np.inf)
    for o, (_, _, _, z_map) in heights.items():
        pick = (orient == o) & (xs >= 0) & (ys >= 0) & (xs < z_map.shape[0]) & (ys < z_map.shape[1])
        z[pick] = z_map[xs[pick], ys[pick]]
    fits = z + size[:, 2] <= container.height + TOLERANCE_CM
    raised = fits & (z > TOLERANCE_CM)
    rects, touching = _contacts(xs[raised], ys[raised], xs[raised] + size[raised, 0],
                                ys[raised] + size[raised, 1], z[raised], extents[:, [0, 1, 3, 4, 5]])  # fmt: skip
    contact = np.zeros((len(order), *rects.shape[1:]))
    touches = np.zeros((len(order), len(extents)), bool)
    contact[raised], touches[raised] = rects, touching
    fits &= ~raised | touches.any(axis=1)
    leaves = np.zeros((LEAF_HOLDER, 8))
    actions: list[tuple[int, int, int]] = []
    for i in np.flatnonzero(fits):
        if raised[i] and not _inside_shrunk_hull(
            contact[i, touches[i]], xs[i] + size[i, 0] / 2, ys[i] + size[i, 1] / 2
        ):
            continue
        sx, sy = size[i, :2]
        leaves[len(actions)] = (xs[i], ys[i], order[i, 2], xs[i] + sx, ys[i] + sy, container.height, 0, 0)
        actions.append((int(xs[i]), int(ys[i]), int(orient[i])))
        if len(actions) == LEAF_HOLDER:
            break
    leaf_valid = np.zeros(LEAF_HOLDER, bool)
    leaf_valid[: len(actions)] = True
    b = obs.box
    next_item = np.array([1.0, 0.0, 0.0, *sorted((cells(b.length), cells(b.width), b.height))])
    return Nodes(internal, internal_valid, leaves, leaf_valid, next_item, actions)
