"""The container's geometric state: placed boxes and the 1 cm heightmap over them."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from robobpp.core.box import Box, ContainerSpec, Placement
from robobpp.core.heightmap import footprint_cells


class ContainerState:
    """Placements plus a float heightmap (cm) kept in step with them.

    The heightmap is the max top height over each cell, which is what a box dropped from above meets.
    """

    def __init__(self, spec: ContainerSpec) -> None:
        self.spec = spec
        self._heightmap = np.zeros(spec.grid_shape, dtype=np.float64)
        self.placements: list[Placement] = []
        #: Each :meth:`add`'s block of cells and the top it raised them to, ``(x0, x1, y0, y1, top)``, in order:
        #: what changed in the heightmap, so that work on it can be brought up to date instead of redone
        #: (:class:`robobpp.core.feasible_grid.FeasibleGrids`).
        self.raises: list[tuple[int, int, int, int, float]] = []
        #: Whether the heightmap is the empty container's raised by ``raises``, all of them: False once the
        #: heightmap is replaced (a physical state's, say).
        self.from_empty = True

    @property
    def heightmap(self) -> np.ndarray:
        return self._heightmap

    @heightmap.setter
    def heightmap(self, heightmap: np.ndarray) -> None:
        self._heightmap = heightmap
        self.from_empty = False

    @classmethod
    def from_placements(cls, spec: ContainerSpec, placements: Iterable[Placement]) -> ContainerState:
        """Rebuild the state from actual poses (e.g. after physics), each taken as its axis-aligned box."""
        state = cls(spec)
        for placement in placements:
            state.add(placement)
        return state

    def drop_height(self, x: float, y: float, length: float, width: float) -> float:
        """Height at which a footprint released from above comes to rest (max of the heightmap under it)."""
        return self._rest(x, y, length, width)[0]

    def _rest(self, x: float, y: float, length: float, width: float) -> tuple[float, tuple[slice, slice]]:
        cells = footprint_cells(x, y, length, width, self.heightmap.shape)
        region = self.heightmap[cells]
        # the ufunc's reduce, as ndarray.max calls it, without the method's Python layer (every Math step)
        return (float(np.maximum.reduce(region, axis=None)) if region.size else 0.0), cells

    def drop(self, box: Box, x: float, y: float, orientation: int, index: int) -> Placement:
        """The placement the box takes when dropped at (x, y): Math Pack's rule (rests on the max height)."""
        return self.drop_on_cells(box, x, y, orientation, index)[0]

    def drop_on_cells(
        self, box: Box, x: float, y: float, orientation: int, index: int
    ) -> tuple[Placement, tuple[slice, slice]]:
        """:meth:`drop`, and the cells under the footprint (for :meth:`add`)."""
        length, width, height = box.dims(orientation)
        z, cells = self._rest(x, y, length, width)
        return Placement(x, y, z, length, width, height, orientation, index), cells

    def add(self, placement: Placement, cells: tuple[slice, slice] | None = None) -> None:
        """Record a placement and raise the heightmap under its footprint to its top (``cells``: its
        :func:`footprint_cells`, when the caller has them)."""
        if cells is None:
            cells = footprint_cells(
                placement.x, placement.y, placement.length, placement.width, self.heightmap.shape
            )
        region = self.heightmap[cells]
        np.maximum(region, placement.top, out=region)
        self.placements.append(placement)
        self.raises.append((cells[0].start, cells[0].stop, cells[1].start, cells[1].stop, placement.top))

    @property
    def placed_volume(self) -> float:
        return sum(p.volume for p in self.placements)

    def volume_under_heightmap(self) -> float:
        """cm³ under the heightmap over the container footprint (1 cm² cells)."""
        # the ufunc's reduce, as ndarray.sum calls it (the same sum), without the method's Python layer
        return float(np.add.reduce(self.heightmap, axis=None))
