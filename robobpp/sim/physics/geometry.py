"""Geometry of actual (possibly moved or tilted) boxes, in cm, with numpy only.

The resting height of a new box and the observed heightmap are computed from the *physical* poses of the
placed boxes, not from where they were meant to be. A tilted box is an oriented box (OBB); vertical rays
through the new footprint find the highest surface under it exactly, which pybullet's own AABBs (inflated
by the contact margin) would not.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from robobpp.core import Placement

#: Cells of the footprint sampled by the vertical rays: at most this far apart, cm.
RAY_SPACING_CM = 1.0


def rotation_matrices(quaternions: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (x, y, z, w) → (N, 3, 3) rotation matrices (box frame → world frame)."""
    q = np.asarray(quaternions, dtype=np.float64).reshape(-1, 4)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1),
        ],
        axis=1,
    )


def aabbs(
    centers: np.ndarray, quaternions: np.ndarray, half_extents: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Exact axis-aligned bounds (lo, hi), each (N, 3), of oriented boxes."""
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    if c.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    rot = rotation_matrices(quaternions)
    reach = np.einsum("nij,nj->ni", np.abs(rot), np.asarray(half_extents, dtype=np.float64).reshape(-1, 3))
    return c - reach, c + reach


def _axis_samples(lo: float, hi: float, tolerance: float) -> np.ndarray:
    a, b = lo + tolerance, hi - tolerance
    if b <= a:
        return np.array([(lo + hi) / 2.0])
    n = max(2, math.ceil((b - a) / RAY_SPACING_CM) + 1)
    return np.linspace(a, b, n)


def surface_height(
    centers: np.ndarray,
    quaternions: np.ndarray,
    half_extents: np.ndarray,
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    tolerance: float = 0.0,
) -> float:
    """Highest point of the boxes met by vertical rays over [x0, x1] × [y0, y1] inset by ``tolerance``.

    0 (the pallet's top) when nothing lies there. Rays are at most ``RAY_SPACING_CM`` apart and include the
    inset edges, so a box corner can hide between rays by under a centimetre, which the release gap and
    the solver absorb.
    """
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    if c.shape[0] == 0:
        return 0.0
    h = np.asarray(half_extents, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(quaternions, dtype=np.float64).reshape(-1, 4)
    lo, hi = aabbs(c, q, h)
    near = (lo[:, 0] < x1 - tolerance) & (hi[:, 0] > x0 + tolerance)
    near &= (lo[:, 1] < y1 - tolerance) & (hi[:, 1] > y0 + tolerance)
    if not near.any():
        return 0.0
    c, h, rot = c[near], h[near], rotation_matrices(q[near])
    xs, ys = _axis_samples(x0, x1, tolerance), _axis_samples(y0, y1, tolerance)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    points = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)  # (P, 3)
    # A few boxes at a time: a long board's footprint holds ~15,000 rays, and all boxes at once made the
    # (B, P, 3) arrays below tens of MB (the worker's peak memory). The result is the same.
    per_chunk = max(1, RAY_BOX_BUDGET // points.shape[0])
    top = -np.inf
    for k in range(0, c.shape[0], per_chunk):
        top = max(
            top, _highest_hit(c[k : k + per_chunk], h[k : k + per_chunk], rot[k : k + per_chunk], points)
        )
    return max(0.0, float(top))


#: Rays × boxes intersected at once by :func:`surface_height` (bounds its temporary arrays to a few MB).
RAY_BOX_BUDGET = 50_000


def _highest_hit(c: np.ndarray, h: np.ndarray, rot: np.ndarray, points: np.ndarray) -> float:
    """Highest exit point of the vertical rays from ``points`` through the boxes they hit (-inf: none)."""
    # Ray r(t) = point + t·ez; in the box frame: a + t·d with a = Rᵀ(point − c), d = Rᵀ·ez.
    a = np.einsum("bji,bpj->bpi", rot, points[None, :, :] - c[:, None, :])  # (B, P, 3)
    d = rot[:, 2, :][:, None, :]  # (B, 1, 3)
    he = h[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-he - a) / d
        t2 = (he - a) / d
    parallel = np.abs(d) < 1e-12
    inside = np.abs(a) <= he
    t_lo = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    t_hi = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    enter, leave = t_lo.max(axis=2), t_hi.min(axis=2)
    hit = enter <= leave
    return float(leave[hit].max()) if hit.any() else -np.inf


def heightmap_from_boxes(
    shape: tuple[int, int],
    centers: np.ndarray,
    quaternions: np.ndarray,
    half_extents: np.ndarray,
    tolerance: float = 0.0,
) -> np.ndarray:
    """1 cm heightmap (cm) of the boxes' actual AABBs, each shrunk horizontally by ``tolerance``.

    The AABB is conservative for a tilted box (its top is where the highest corner is), which keeps a
    policy from aiming into a leaning box. The shrink keeps settling noise of a millimetre from claiming a
    whole extra row of cells.
    """
    hm = np.zeros(shape, dtype=np.float64)
    lo, hi = aabbs(centers, quaternions, half_extents)
    for (ax, ay, _az), (bx, by, bz) in zip(lo, hi, strict=True):
        i0 = max(0, math.floor(ax + tolerance))
        j0 = max(0, math.floor(ay + tolerance))
        i1 = min(shape[0], math.ceil(bx - tolerance))
        j1 = min(shape[1], math.ceil(by - tolerance))
        if i1 > i0 and j1 > j0 and bz > 0:
            region = hm[i0:i1, j0:j1]
            np.maximum(region, bz, out=region)
    return hm


def observed_heightmap(
    shape: tuple[int, int],
    placements: Sequence[Placement],
    shrink_cm: float,
    resolution_cm: float,
) -> np.ndarray:
    """The heightmap a Physics or Execution Pack policy observes, from the placements it observes (each box's
    min corner as rounded for the observation, its dims and its quaternion): the bounds of each box as it
    stands, shrunk by ``shrink_cm``, rounded to ``resolution_cm``. The setting and the wire protocol's
    rebuild both call this, so a served policy sees to the bit what an in-process one sees (built from the
    unrounded poses, a box edge within the rounding of a cell boundary claimed the cell on one side only)."""
    if not placements:
        return np.zeros(shape, dtype=np.float64)
    halves = np.array([(p.length, p.width, p.height) for p in placements], dtype=np.float64) / 2
    centers = np.array([(p.x, p.y, p.z) for p in placements], dtype=np.float64) + halves
    quaternions = np.array([p.quaternion or (0.0, 0.0, 0.0, 1.0) for p in placements], dtype=np.float64)
    heightmap = heightmap_from_boxes(shape, centers, quaternions, halves, shrink_cm)
    return np.round(heightmap / resolution_cm) * resolution_cm if resolution_cm > 0 else heightmap


def _overlaps(lo: np.ndarray, hi: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray) -> np.ndarray:
    """Mask of the bounds (lo, hi) that overlap the box [box_lo, box_hi] with positive volume."""
    overlapping: np.ndarray = ((np.minimum(hi, box_hi) - np.maximum(lo, box_lo)) > 1e-9).all(axis=1)
    return overlapping


def clear_shift(
    lo: np.ndarray, hi: np.ndarray, planned: Placement, gap: float, tolerance: float, clearance: float
) -> tuple[float, float]:
    """Horizontal shift (cm) that moves ``planned``, released ``gap`` above its height, out of every box
    bound (lo, hi) it would start inside, along the axis that needs less, by the overlap + ``clearance``.

    Only overlaps of at most ``tolerance`` are shifted away (deeper ones are what the box rests on); when
    the needed shifts conflict (neighbours on both sides) or the shifted box would still start inside a
    box, no shift: (0, 0), and the solver separates them as before.
    """
    x0, y0, z0 = planned.x, planned.y, planned.z + gap
    box_lo = np.array([x0, y0, z0])
    box_hi = box_lo + np.array([planned.length, planned.width, planned.height])
    hits = _overlaps(lo, hi, box_lo, box_hi)
    if not hits.any():
        return 0.0, 0.0
    shift = np.zeros(2)
    lo_h, hi_h = lo[hits, :2], hi[hits, :2]
    # Per blocking box and axis: the shift that ends the overlap, towards the side away from its centre.
    centre = (box_lo[:2] + box_hi[:2]) / 2
    away = np.where((lo_h + hi_h) / 2 > centre, lo_h - box_hi[:2] - clearance, hi_h - box_lo[:2] + clearance)
    for need in away:
        axis = int(np.argmin(np.abs(need)))
        if abs(need[axis]) > tolerance + clearance:
            return 0.0, 0.0
        if shift[axis] * need[axis] < 0:  # pushed from both sides along this axis
            return 0.0, 0.0
        shift[axis] = need[axis] if abs(need[axis]) > abs(shift[axis]) else shift[axis]
    moved_lo = box_lo + np.array([shift[0], shift[1], 0.0])
    moved_hi = box_hi + np.array([shift[0], shift[1], 0.0])
    if _overlaps(lo, hi, moved_lo, moved_hi).any():
        return 0.0, 0.0
    return float(shift[0]), float(shift[1])
