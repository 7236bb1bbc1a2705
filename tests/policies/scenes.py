"""Hand-built observations: a container, some placed boxes, the box to place."""

from __future__ import annotations

from collections.abc import Sequence

from robobpp.core import Box, ContainerSpec, ContainerState, Observation, Placement


def scene(
    container: tuple[float, float, float],
    placed: Sequence[tuple[float, float, float, float, float]],
    box: tuple[float, float, float],
    physical: bool = False,
) -> Observation:
    """``placed`` holds (x, y, length, width, height) of boxes dropped in that order (each rests where it lands).

    ``physical`` makes it a state observed after physics (upright attitudes), where the support rule applies.
    """
    attitude = (0.0, 0.0, 0.0, 1.0) if physical else None
    spec = ContainerSpec(*container)
    state = ContainerState(spec)
    for k, (x, y, length, width, height) in enumerate(placed):
        z = state.drop_height(x, y, length, width)
        state.add(Placement(x, y, z, length, width, height, 0, k, attitude))
    heightmap = state.heightmap.view()
    heightmap.flags.writeable = False
    return Observation("scene", len(placed), spec, tuple(state.placements), heightmap, Box(*box))
