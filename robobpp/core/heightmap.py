"""Heightmap arithmetic on a 1 cm grid.

Cell (i, j) covers [i, i+1) × [j, j+1) cm. A footprint covers every cell its interior overlaps, so a box
with non-integer size or position is treated conservatively (it rests on the highest cell it touches).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

_EPS = 1e-6


def footprint_cells(
    x: float, y: float, length: float, width: float, shape: tuple[int, int]
) -> tuple[slice, slice]:
    """Cells under the footprint [x, x+length) × [y, y+width), clipped to the grid."""
    i0 = max(0, math.floor(x + _EPS))
    j0 = max(0, math.floor(y + _EPS))
    i1 = min(shape[0], math.ceil(x + length - _EPS))
    j1 = min(shape[1], math.ceil(y + width - _EPS))
    return slice(i0, max(i0, i1)), slice(j0, max(j0, j1))


def cells_spanned(size: float) -> int:
    """Cells an integer-aligned footprint of ``size`` cm covers."""
    return max(1, math.ceil(size - _EPS))


def _doubling(flat: np.ndarray, window: int, stride: int, combine: np.ufunc) -> list[np.ndarray]:
    """The doubling chain of ``combine`` along one axis of a flattened C-ordered grid whose step along that axis is
    ``stride`` elements: entry k holds, at flat index i, ``combine`` of ``flat[i + j * stride]`` for j < 2**k; up
    to the largest power of two not above ``window``."""
    chain = [flat]
    span = 1
    while span * 2 <= window:
        m = chain[-1]
        shift = span * stride
        chain.append(combine(m[:-shift], m[shift:]))
        span *= 2
    return chain


def _from_chain(
    chain: list[np.ndarray], window: int, stride: int, size: int, combine: np.ufunc
) -> np.ndarray:
    """``combine`` over ``window`` consecutive steps at the first ``size`` flat indices: two overlapping
    power-of-two runs of the chain cover any window (O(n log window) in all)."""
    k = window.bit_length() - 1
    m = chain[k]
    shift = (window - (1 << k)) * stride
    out: np.ndarray = combine(m[:size], m[shift : shift + size])
    return out


def _windows(a: np.ndarray, footprints: Sequence[tuple[float, float]], combine: np.ufunc) -> list[np.ndarray]:
    """``combine`` of ``a`` over each ``length`` × ``width`` footprint at every integer position where it lies
    inside the grid: per footprint shape (L - l + 1, W - w + 1), possibly empty.

    Both passes run on the flattened grid, so every numpy call is one contiguous loop (on a 2-D slice numpy loops
    once per row): a shift by ``stride = W`` elements is a shift by one row, a shift by one element one column;
    a window along y that runs past the row's end wraps into the next row, but only at positions past
    ``W - w``, which are cut off. The row pass's doubling chain is shared by every footprint (the two
    orientations of a box): only its last combination differs.
    """
    nx, ny = a.shape
    flat = np.ascontiguousarray(a).reshape(-1)
    spans = [(cells_spanned(length), cells_spanned(width)) for length, width in footprints]
    fitting = [lc for lc, wc in spans if lc <= nx and wc <= ny]
    rows_chain = _doubling(flat, max(fitting, default=1), ny, combine)
    out = []
    for lc, wc in spans:
        if lc > nx or wc > ny:
            out.append(np.empty((max(0, nx - lc + 1), max(0, ny - wc + 1)), dtype=a.dtype))
            continue
        ox, oy = nx - lc + 1, ny - wc + 1
        rows = _from_chain(rows_chain, lc, ny, ox * ny, combine)  # positions (x, any y), flat
        cols = _from_chain(_doubling(rows, wc, 1, combine), wc, 1, ox * ny - wc + 1, combine)
        # (x, y) for y < oy sits at flat index x * ny + y < len(cols): a strided view, no copy
        item = cols.itemsize
        out.append(np.lib.stride_tricks.as_strided(cols, (ox, oy), (ny * item, item), writeable=False))
    return out


def drop_height_map(heightmap: np.ndarray, length: float, width: float) -> np.ndarray:
    """Resting height for every integer position (x, y) of a ``length`` × ``width`` footprint.

    Entry [x, y] is the max of the heightmap over the footprint whose min corner is (x, y); only positions
    where the footprint lies inside the grid are returned, so the shape is (L - l + 1, W - w + 1) (possibly
    empty when the box is larger than the container). Read-only.
    """
    return _windows(heightmap, [(length, width)], np.maximum)[0]


def window_all(cells: np.ndarray, length: float, width: float) -> np.ndarray:
    """Whether every cell under a ``length`` × ``width`` footprint is True, at each position of
    :func:`drop_height_map`.

    With ``cells = heightmap + height <= limit`` that is exactly ``drop_height_map(heightmap, length, width) +
    height <= limit`` — whether a box of ``height`` dropped there keeps its top within ``limit`` — without the
    resting heights: float addition is monotone, so the highest cell under the box passes iff every cell does.
    A sliding "all" over booleans, about 3 times faster than the sliding max over floats.
    """
    return windows_all(cells, [(length, width)])[0]


def windows_all(cells: np.ndarray, footprints: Sequence[tuple[float, float]]) -> list[np.ndarray]:
    """:func:`window_all` for several footprints over the same cells (a box's orientations), sharing work."""
    if cells.all():  # nothing in the way (an empty container, a low pile): every position that fits the grid
        nx, ny = cells.shape
        spans = ((cells_spanned(length), cells_spanned(width)) for length, width in footprints)
        return [np.ones((max(0, nx - lc + 1), max(0, ny - wc + 1)), bool) for lc, wc in spans]
    return _windows(cells, footprints, np.logical_and)


def highest_base(height: float, limit: float) -> float:
    """The highest resting height at which a box of ``height`` keeps its top within ``limit``: ``base + height <=
    limit`` exactly when ``base <= highest_base(height, limit)``, in floating point too (rounded addition is
    monotone, so the passing bases are those up to the largest one), so a heightmap is thresholded with one
    comparison instead of an addition and a comparison."""
    base = limit - height
    while base + height > limit:
        base = math.nextafter(base, -math.inf)
    while math.nextafter(base, math.inf) + height <= limit:
        base = math.nextafter(base, math.inf)
    return base
