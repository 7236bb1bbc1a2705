"""Empty maximal spaces (EMS) of a top-loaded container, derived from its heightmap.

A box is released from above and rests on the heightmap, so the only space a policy can use is the space
*above* the terrain. An EMS here is a maximal empty cuboid ``[x0, x1) × [y0, y1) × [z0, H)`` of that space:
every heightmap cell in the rectangle is ≤ ``z0``, it cannot be widened in x or y, and ``z0`` is the
highest cell under it. The top is always the container height ``H`` (anything above the terrain is free).
Spaces under overhangs exist physically but cannot be reached from above, so they are not listed.

The set is computed with the difference process of Lai & Chan (1997): start from the whole container and,
for every obstacle, replace each space it cuts by the (up to five) slabs left of, right of, behind, in front
of and above it, then drop spaces contained in others. The obstacles are the heightmap decomposed into
constant-height rectangles (each a column from the floor to its height), so the EMS always match
``obs.heightmap`` — the *actual* state, which after physics may differ from what the policy planned.

:class:`EmsTracker` keeps the set between steps: when the new heightmap only rose (Math Pack, or physics
that moved nothing), only the raised cells are cut in; anything else (a box slid or fell) rebuilds from
scratch. Coordinates are 1 cm cells (integers); ``z0`` is a float.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from robobpp.core import EpisodeInfo, Observation, drop_height_map
from robobpp.core.feasibility import TOLERANCE_CM
from robobpp.core.heightmap import cells_spanned
from robobpp.policies.base import BasePolicy

#: Heights closer than this are the same level (cm); physics leaves float noise on box tops.
HEIGHT_EPS = 1e-6


@dataclass(frozen=True, slots=True)
class EmsSet:
    """EMS as parallel arrays: ``rects[k] = (x0, y0, x1, y1)`` in cells, ``z0[k]`` the floor, ``height`` H."""

    rects: np.ndarray  # (n, 4) int64
    z0: np.ndarray  # (n,) float64
    height: float

    def __len__(self) -> int:
        return len(self.z0)

    @property
    def dx(self) -> np.ndarray:
        dx: np.ndarray = self.rects[:, 2] - self.rects[:, 0]
        return dx

    @property
    def dy(self) -> np.ndarray:
        dy: np.ndarray = self.rects[:, 3] - self.rects[:, 1]
        return dy

    @property
    def dz(self) -> np.ndarray:
        return self.height - self.z0

    def as_tuples(self) -> list[tuple[int, int, int, int, float]]:
        """Sorted ``(x0, y0, x1, y1, z0)`` tuples — handy in tests and for reading."""
        return sorted(
            (int(r[0]), int(r[1]), int(r[2]), int(r[3]), float(z))
            for r, z in zip(self.rects, self.z0, strict=True)
        )


def empty_container(shape: tuple[int, int], height: float) -> EmsSet:
    """The one EMS of an empty container: the whole of it."""
    return EmsSet(np.array([[0, 0, shape[0], shape[1]]], dtype=np.int64), np.zeros(1), float(height))


def _contained(
    new_r: np.ndarray, new_z: np.ndarray, all_r: np.ndarray, all_z: np.ndarray, offset: int
) -> np.ndarray:
    """Mask of the new spaces that lie inside another space (``all`` holds them at ``offset`` onward).

    Identical spaces: only the first copy survives, so duplicates from two cut spaces collapse to one.
    """
    inside = (
        (all_r[None, :, 0] <= new_r[:, None, 0])
        & (all_r[None, :, 1] <= new_r[:, None, 1])
        & (all_r[None, :, 2] >= new_r[:, None, 2])
        & (all_r[None, :, 3] >= new_r[:, None, 3])
        & (all_z[None, :] <= new_z[:, None] + HEIGHT_EPS)
    )
    equal = (all_r[None, :, :] == new_r[:, None, :]).all(axis=2) & (
        np.abs(all_z[None, :] - new_z[:, None]) <= HEIGHT_EPS
    )
    own = np.arange(len(new_z))[:, None] + offset
    later_or_self = np.arange(len(all_z))[None, :] >= own
    inside &= ~(equal & later_or_self)  # an equal copy only counts if it comes earlier
    # numpy types any(axis=...) as possibly a scalar (a 1-D input); a 2-D input gives one flag per row
    return cast(np.ndarray, inside.any(axis=1))


def cut(ems: EmsSet, obstacle: tuple[int, int, int, int, float]) -> EmsSet:
    """Difference process step: remove the column ``[a0, a1) × [b0, b1) × [0, top)`` from every space."""
    a0, b0, a1, b1, top = obstacle
    r, z = ems.rects, ems.z0
    hit = (r[:, 0] < a1) & (r[:, 2] > a0) & (r[:, 1] < b1) & (r[:, 3] > b0) & (z < top - HEIGHT_EPS)
    if not hit.any():
        return ems
    keep_r, keep_z = r[~hit], z[~hit]
    cr, cz = r[hit], z[hit]
    pieces_r: list[np.ndarray] = []
    pieces_z: list[np.ndarray] = []
    # (which column must stick out past the obstacle, on which side, which column becomes the bound)
    sides = (
        (cr[:, 0] < a0, 2, a0),  # left of it: x1 := a0
        (cr[:, 2] > a1, 0, a1),  # right of it: x0 := a1
        (cr[:, 1] < b0, 3, b0),  # behind it: y1 := b0
        (cr[:, 3] > b1, 1, b1),  # in front of it: y0 := b1
    )
    for ok, column, bound in sides:
        if ok.any():
            piece = cr[ok].copy()
            piece[:, column] = bound
            pieces_r.append(piece)
            pieces_z.append(cz[ok])
    if top < ems.height - HEIGHT_EPS:  # the slab above the obstacle
        pieces_r.append(cr.copy())
        pieces_z.append(np.full(len(cz), float(top)))
    if not pieces_r:
        return EmsSet(keep_r, keep_z, ems.height)
    new_r = np.concatenate(pieces_r)
    new_z = np.concatenate(pieces_z)
    all_r = np.concatenate([keep_r, new_r])
    all_z = np.concatenate([keep_z, new_z])
    drop = _contained(new_r, new_z, all_r, all_z, len(keep_z))
    return EmsSet(np.concatenate([keep_r, new_r[~drop]]), np.concatenate([keep_z, new_z[~drop]]), ems.height)


def height_rectangles(
    heightmap: np.ndarray, mask: np.ndarray | None = None
) -> list[tuple[int, int, int, int, float]]:
    """Decompose the (masked) positive part of a heightmap into constant-height rectangles.

    Runs of equal height along y in each row are merged with identical runs of the following rows; the
    union of the rectangles, each a column up to its height, gives back the heightmap exactly.
    """
    hm = np.asarray(heightmap, dtype=np.float64)
    valid = hm > HEIGHT_EPS if mask is None else mask & (hm > HEIGHT_EPS)
    if not valid.any():
        return []
    rows = np.flatnonzero(valid.any(axis=1))
    cols = np.flatnonzero(valid.any(axis=0))
    i_lo, i_hi, j_lo, j_hi = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    sub = np.where(valid[i_lo:i_hi, j_lo:j_hi], hm[i_lo:i_hi, j_lo:j_hi], np.nan)
    # runs along y: a run starts at the first column or where the value changes (NaN-aware)
    prev, nxt = sub[:, :-1], sub[:, 1:]
    changed = ~((prev == nxt) | (np.isnan(prev) & np.isnan(nxt)))
    starts = np.concatenate([np.ones((sub.shape[0], 1), dtype=bool), changed], axis=1)
    row, j0 = np.nonzero(starts)
    flat = row * sub.shape[1] + j0
    j1 = np.append(flat[1:], sub.size) - row * sub.shape[1]
    j1 = np.minimum(j1, sub.shape[1])
    value = sub[row, j0]
    solid = ~np.isnan(value)
    row, j0, j1, value = row[solid], j0[solid], j1[solid], value[solid]
    if row.size == 0:
        return []
    # merge identical runs of consecutive rows: sort by (j0, j1, value, row), cut where the chain breaks
    order = np.lexsort((row, value, j1, j0))
    row, j0, j1, value = row[order], j0[order], j1[order], value[order]
    same = (j0[1:] == j0[:-1]) & (j1[1:] == j1[:-1]) & (value[1:] == value[:-1]) & (row[1:] == row[:-1] + 1)
    first = np.flatnonzero(np.concatenate([[True], ~same]))
    last = np.append(first[1:], row.size) - 1
    return list(
        zip(
            (i_lo + row[first]).tolist(),
            (j_lo + j0[first]).tolist(),
            (i_lo + row[last] + 1).tolist(),
            (j_lo + j1[first]).tolist(),
            value[first].tolist(),
            strict=True,
        )
    )


def ems_from_heightmap(heightmap: np.ndarray, height: float) -> EmsSet:
    """All EMS of a container of ``height`` whose terrain is ``heightmap`` (from scratch)."""
    ems = empty_container(heightmap.shape, height)
    # tallest first: each later, lower column then cuts few spaces (7 ms instead of 49 ms for a full
    # 80-box Repetitive container; the result is the same in any order)
    for rect in sorted(height_rectangles(heightmap), key=lambda r: -r[4]):
        ems = cut(ems, rect)
    return ems


class EmsTracker:
    """Keeps the EMS of the observed container between steps (incremental when the heightmap only rose)."""

    def __init__(self) -> None:
        self._heightmap: np.ndarray | None = None
        self._ems: EmsSet | None = None
        #: How many times the set was rebuilt from scratch (tests and benchmarks read it).
        self.rebuilds = 0

    def reset(self) -> None:
        self._heightmap = None
        self._ems = None

    def update(self, heightmap: np.ndarray, height: float) -> EmsSet:
        hm = np.asarray(heightmap, dtype=np.float64)
        prev, ems = self._heightmap, self._ems
        if prev is None or ems is None or prev.shape != hm.shape or ems.height != height:
            ems = self._rebuild(hm, height)
        else:
            changed = hm != prev
            if changed.any():
                if (hm[changed] < prev[changed]).any():  # something moved down or away: start over
                    ems = self._rebuild(hm, height)
                else:
                    for rect in height_rectangles(hm, changed):
                        ems = cut(ems, rect)
        self._heightmap = hm.copy()
        self._ems = ems
        return ems

    def _rebuild(self, hm: np.ndarray, height: float) -> EmsSet:
        self.rebuilds += 1
        return ems_from_heightmap(hm, height)


@dataclass(frozen=True, slots=True)
class Candidates:
    """Placements at EMS corners: min corner ``(x, y)`` in cells, orientation, resting ``z``, source EMS.

    ``lc, wc`` are the box's footprint in cells and ``h`` its height for each candidate's orientation.
    """

    x: np.ndarray
    y: np.ndarray
    orientation: np.ndarray
    z: np.ndarray
    ems: np.ndarray
    lc: np.ndarray
    wc: np.ndarray
    h: np.ndarray

    def __len__(self) -> int:
        return len(self.x)

    def take(self, mask: np.ndarray) -> Candidates:
        return Candidates(*(getattr(self, f)[mask] for f in self.__slots__))


def _resting_heights(heightmap: np.ndarray, xs: np.ndarray, ys: np.ndarray, lc: int, wc: int) -> np.ndarray:
    """Resting height of an ``lc × wc`` footprint at each (xs, ys): one vectorised drop map, then a lookup."""
    heights: np.ndarray = drop_height_map(heightmap, lc, wc)[xs, ys]
    return heights


def ems_candidates(obs: Observation, ems: EmsSet, corners: int = 1, dedupe: bool = True) -> Candidates:
    """Every (EMS, orientation) where the box fits, placed at the EMS's min corner (``corners=1``) or at its
    four bottom corners (``corners=4``), with the resting height from the heightmap. With ``dedupe`` a
    position reached from several spaces is kept once (from the first of them); without, once per space —
    for scores that depend on the space the box goes into.
    """
    container = obs.container
    hm = obs.heightmap
    grid_x, grid_y = hm.shape
    parts: list[tuple[np.ndarray, ...]] = []
    for orientation in obs.orientations:
        length, width, height = obs.box.dims(orientation)
        lc, wc = cells_spanned(length), cells_spanned(width)
        if lc > grid_x or wc > grid_y:
            continue
        fits = (ems.dx >= lc) & (ems.dy >= wc) & (ems.dz >= height - TOLERANCE_CM)
        idx = np.flatnonzero(fits)
        if idx.size == 0:
            continue
        r = ems.rects[idx]
        xs_opts = [r[:, 0]] if corners == 1 else [r[:, 0], r[:, 2] - lc]
        ys_opts = [r[:, 1]] if corners == 1 else [r[:, 1], r[:, 3] - wc]
        xs = np.concatenate([x for x in xs_opts for _ in ys_opts])
        ys = np.concatenate([y for _ in xs_opts for y in ys_opts])
        src = np.tile(idx, len(xs_opts) * len(ys_opts))
        # the real container bounds (a non-integer container leaves a partial last cell)
        inside = (xs + length <= container.length + TOLERANCE_CM) & (
            ys + width <= container.width + TOLERANCE_CM
        )
        xs, ys, src = xs[inside], ys[inside], src[inside]
        key = (xs * (grid_y + 1) + ys) * (len(ems) + 1) + (0 if dedupe else src)
        _, first = np.unique(key, return_index=True)
        first.sort()
        xs, ys, src = xs[first], ys[first], src[first]
        z = _resting_heights(hm, xs, ys, lc, wc)
        n = len(xs)
        parts.append(
            (xs, ys, np.full(n, orientation), z, src, np.full(n, lc), np.full(n, wc), np.full(n, height))
        )
    if not parts:
        empty_i = np.zeros(0, dtype=np.int64)
        return Candidates(empty_i, empty_i, empty_i, np.zeros(0), empty_i, empty_i, empty_i, np.zeros(0))
    cols = list(zip(*parts, strict=True))
    return Candidates(*(np.concatenate(c) for c in cols))


class EmsPolicy(BasePolicy):
    """Base of the EMS-driven policies: keeps an :class:`EmsTracker` in step with the observations."""

    def __init__(self) -> None:
        self._tracker = EmsTracker()

    def reset(self, info: EpisodeInfo) -> None:
        self._tracker.reset()

    def spaces(self, obs: Observation) -> EmsSet:
        return self._tracker.update(obs.heightmap, obs.container.height)
