"""Every top-down placement inside each dataset's container is reachable from the layout."""

from __future__ import annotations

import numpy as np
import pytest

from robobpp.core import Box
from robobpp.datasets.registry import DATASETS
from robobpp.sim.execution import Layout
from robobpp.sim.physics.world import PALLET_HEIGHT_M


@pytest.mark.parametrize("dataset", sorted(DATASETS))
def test_container_volume_is_reachable(dataset: str) -> None:
    container = DATASETS[dataset].container
    layout = Layout(container, floor_z=-PALLET_HEIGHT_M)
    home = layout.home
    missed = []
    # TCP = top-face centre of the box; from the deck up to 5 cm above the top (the approach pose).
    for x in np.linspace(0, container.length, 9):
        for y in np.linspace(0, container.width, 9):
            for z in np.linspace(0, container.height + 5, 6):
                for orientation in (0, 1):
                    if layout.place_ik(np.array([x, y, z]) / 100, orientation, home) is None:
                        missed.append((x, y, z, orientation))
    assert not missed, f"{len(missed)} unreachable placements, e.g. {missed[:3]}"


@pytest.mark.parametrize("dataset", sorted(DATASETS))
def test_pick_station_is_clear_of_the_pallet_and_reachable(dataset: str) -> None:
    container = DATASETS[dataset].container
    layout = Layout(container, floor_z=-PALLET_HEIGHT_M)
    centre, half = layout.conveyor_box()
    # the conveyor's footprint stays off the pallet
    assert centre[0] + half[0] < 0 or centre[1] - half[1] > container.width / 100
    panel = Box(250, 120, 2, 10)  # the longest panel, still clear of the pallet on the belt
    box_centre, yaw = layout.pick_box_pose(panel)
    tcp = box_centre + [0, 0, panel.height / 200]
    assert layout.ik(tcp, layout.tool_rotation(yaw), layout.home) is not None
    reach = 1.25  # half the panel's length, along world y at the pick
    assert abs(np.cos(yaw)) < 1e-9
    assert box_centre[0] + panel.width / 200 < 0 or box_centre[1] - reach > container.width / 100
