"""Where a box may go: the (x, y, orientation) grid of feasible placements on a heightmap — inside the container and
below its top, what every setting accepts (:func:`robobpp.core.check_action`) — computed at once
(:func:`orientation_fits`, :func:`feasible_grid`) or kept up to date box after box (:class:`FeasibleGrids`, the
Gym env's mask).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from robobpp.core.box import ORIENTATIONS, Box, ContainerSpec
from robobpp.core.container import ContainerState
from robobpp.core.feasibility import TOLERANCE_CM
from robobpp.core.heightmap import cells_spanned, highest_base, windows_all

#: (orientation, its (length, width, height), the positions (x, y) where the box stays inside the container and
#: keeps its top within the container's height).
OrientationFits = tuple[int, tuple[float, float, float], np.ndarray]


def fitting_orientations(
    box: Box, container: ContainerSpec, orientations: Sequence[int] = ORIENTATIONS
) -> list[tuple[int, tuple[float, float, float]]]:
    """The orientations whose footprint fits the container's at all, with the oriented dimensions."""
    oriented = [(o, box.dims(o)) for o in orientations]
    return [
        (o, dims)
        for o, dims in oriented
        if dims[0] <= container.length + TOLERANCE_CM and dims[1] <= container.width + TOLERANCE_CM
    ]


def orientation_fits(
    heightmap: np.ndarray, box: Box, container: ContainerSpec, orientations: Sequence[int] = ORIENTATIONS
) -> list[OrientationFits]:
    """Per orientation in which the box fits the container at all, in orientation order: where it may go.

    Entry [x, y] of a map is for the box's min corner at (x, y) cm; the map's shape (nx - l + 1, ny - w + 1)
    implies the bounds. The height test is exactly ``drop_height_map(...) + height <= limit``: a box keeps its
    top within the limit iff every cell under it is at most :func:`highest_base` (read-only maps).
    """
    shown = fitting_orientations(box, container, orientations)
    out: list[OrientationFits] = []
    for height in dict.fromkeys(dims[2] for _, dims in shown):  # orientations turned about z share it
        same = [(o, dims) for o, dims in shown if dims[2] == height]
        below = heightmap <= highest_base(height, container.height + TOLERANCE_CM)
        fits = windows_all(below, [(dims[0], dims[1]) for _, dims in same])
        out.extend((o, dims, f) for (o, dims), f in zip(same, fits, strict=True) if f.size)
    out.sort(key=lambda entry: entry[0])
    return out


def feasible_grid(
    heightmap: np.ndarray, box: Box, container: ContainerSpec, orientations: Sequence[int] = ORIENTATIONS
) -> np.ndarray:
    """The boolean (x, y, orientation) grid of feasible placements (a new array, shape grid × orientations)."""
    nx, ny = container.grid_shape
    grid = np.zeros((nx, ny, len(orientations)), bool)
    for orientation, _, fits in orientation_fits(heightmap, box, container, orientations):
        grid[: fits.shape[0], : fits.shape[1], orientations.index(orientation)] = fits
    return grid


@dataclass
class _Kept:
    """One box size's grid and the state it is up to date with."""

    grid: np.ndarray
    base: float  # highest_base for the box's height
    spans: list[tuple[int, int]]  # cells the footprint spans (x, y), per orientation
    state: ContainerState
    heightmap: np.ndarray  # the state's heightmap array it was computed on (replaced wholesale: recompute)
    seen: int  # how many of the state's raises it includes


class FeasibleGrids:
    """:func:`feasible_grid` for the boxes of one container, one after another, brought up to date instead of
    recomputed where it can be.

    A grid is kept per box size (the ``sizes`` most recent). When a box of a kept size comes again on the same
    :class:`ContainerState`, the grid catches up with the blocks of cells the state raised since
    (``ContainerState.raises``): a raised block whose new top leaves no room for the box rules out exactly the
    positions whose footprint covers it (its cells are all too high now; every other cell is unchanged); a block
    that still leaves room changes nothing (a cell's status can only change by rising above the box's highest
    base). A few slices per placement instead of a sliding window over the whole grid; exact, which
    ``tests/core/test_feasible_grid.py`` checks box after box against :func:`feasible_grid`. Runs of equal boxes
    are common (most consecutive boxes of a Repetitive group; about 14 sizes per group of 80). A size not kept
    on a state with few raises (``ContainerState.from_empty``: its heightmap is the empty container's raised by
    them) starts from its grid on the empty container (the bounds alone) and catches up. A state with a
    replaced heightmap (a physical setting observes a new one after every step) or a long catch-up recomputes.

    The returned grid is the instance's own and changes on later calls: copy what you keep.
    """

    #: More raises to replay than this, and recomputing is cheaper.
    MAX_CATCH_UP = 16

    def __init__(
        self, container: ContainerSpec, orientations: Sequence[int] = ORIENTATIONS, sizes: int = 8
    ) -> None:
        self.container = container
        self.orientations = tuple(orientations)
        self.sizes = sizes
        self._limit = container.height + TOLERANCE_CM
        self._kept: OrderedDict[tuple[float, float, float], _Kept] = OrderedDict()

    def __call__(self, state: ContainerState, box: Box) -> np.ndarray:
        """The feasible (x, y, orientation) grid of ``box`` on ``state``."""
        size = (box.length, box.width, box.height)
        kept = self._kept.get(size)
        if (
            kept is None
            or kept.state is not state
            or kept.heightmap is not state.heightmap
            or len(state.raises) - kept.seen > self.MAX_CATCH_UP
        ):
            if state.from_empty and len(state.raises) <= self.MAX_CATCH_UP:
                # few boxes placed: start from the grid on the empty container and catch up
                kept = self._on_empty(state, box)
                self._catch_up(kept)
            else:
                kept = self._compute(state, box)
            self._kept[size] = kept
            if len(self._kept) > self.sizes:
                self._kept.popitem(last=False)
        else:
            self._catch_up(kept)
        self._kept.move_to_end(size)
        return kept.grid

    def _on_empty(self, state: ContainerState, box: Box) -> _Kept:
        """The box's grid on the empty container, to catch up with all of ``state``'s raises: every position where
        the footprint fits the container, if the box fits under its top at all (what :func:`orientation_fits`
        gives on a heightmap of zeros, without sliding over it)."""
        kept = self._kept_of(
            state, box, np.zeros((*self.container.grid_shape, len(self.orientations)), bool), 0
        )
        if kept.base >= 0.0:  # the floor leaves room for the box
            nx, ny = self.container.grid_shape
            for orientation, _ in fitting_orientations(box, self.container, self.orientations):
                index = self.orientations.index(orientation)
                lc, wc = kept.spans[index]
                kept.grid[: max(0, nx - lc + 1), : max(0, ny - wc + 1), index] = True
        return kept

    def _compute(self, state: ContainerState, box: Box) -> _Kept:
        grid = feasible_grid(state.heightmap, box, self.container, self.orientations)
        return self._kept_of(state, box, grid, len(state.raises))

    def _kept_of(self, state: ContainerState, box: Box, grid: np.ndarray, seen: int) -> _Kept:
        """``grid`` for ``box``, up to date with ``seen`` of ``state``'s raises."""
        spans = [
            (cells_spanned(length), cells_spanned(width))
            for length, width, _ in (box.dims(o) for o in self.orientations)
        ]
        return _Kept(grid, highest_base(box.height, self._limit), spans, state, state.heightmap, seen)

    def _catch_up(self, kept: _Kept) -> None:
        raises = kept.state.raises
        for x0, x1, y0, y1, top in raises[kept.seen :]:
            if top > kept.base:  # every cell of the block is at least ``top`` now: too high for the box
                for index, (lc, wc) in enumerate(kept.spans):
                    kept.grid[max(0, x0 - lc + 1) : x1, max(0, y0 - wc + 1) : y1, index] = False
        kept.seen = len(raises)
