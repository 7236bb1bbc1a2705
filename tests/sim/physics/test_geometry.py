"""Heights under a footprint from actual (moved, tilted) boxes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robobpp.sim.physics.geometry import aabbs, heightmap_from_boxes, surface_height

UPRIGHT = (0.0, 0.0, 0.0, 1.0)


def _tilt_about_x(angle: float) -> tuple[float, float, float, float]:
    return (math.sin(angle / 2), 0.0, 0.0, math.cos(angle / 2))


def test_nothing_under_the_footprint_is_the_deck() -> None:
    assert surface_height(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), 0, 0, 10, 10) == 0.0
    c, q, h = np.array([[50.0, 50, 5]]), np.array([UPRIGHT]), np.array([[5.0, 5, 5]])
    assert surface_height(c, q, h, 0, 0, 10, 10) == 0.0


def test_upright_box_top() -> None:
    c, q, h = np.array([[10.0, 10, 7]]), np.array([UPRIGHT]), np.array([[5.0, 5, 7]])
    assert surface_height(c, q, h, 0, 0, 30, 30) == pytest.approx(14)


def test_tilted_box_highest_point_under_the_footprint() -> None:
    """A 20×20×20 cube turned 45° about x: its top edge is at the centre height + 10·√2, along y = centre."""
    c, q, h = np.array([[10.0, 20, 20]]), np.array([_tilt_about_x(math.pi / 4)]), np.array([[10.0, 10, 10]])
    assert surface_height(c, q, h, 0, 0, 20, 40) == pytest.approx(20 + 10 * math.sqrt(2), abs=1e-6)
    # A footprint that only covers y ∈ [25, 40]: the slope there peaks at y = 25, 5 cm off the ridge.
    assert surface_height(c, q, h, 0, 25, 20, 40) == pytest.approx(20 + 10 * math.sqrt(2) - 5, abs=1e-6)
    lo, hi = aabbs(c, q, h)
    assert hi[0, 2] == pytest.approx(20 + 10 * math.sqrt(2))


def test_tolerance_ignores_a_sliver_of_overlap() -> None:
    """A neighbour reaching 3 mm into the footprint (settling noise) does not lift the new box."""
    c, q, h = np.array([[-9.7, 10, 10]]), np.array([UPRIGHT]), np.array([[10.0, 10, 10]])
    assert surface_height(c, q, h, 0, 0, 20, 20, tolerance=0.5) == 0.0
    assert surface_height(c, q, h, 0, 0, 20, 20, tolerance=0.0) == pytest.approx(20)


def test_heightmap_covers_actual_bounds() -> None:
    """The tall box slid 4 mm towards the low one: the low box keeps its cells in the heightmap."""
    c = np.array([[10.4, 10, 5], [30.0, 10, 2.5]])
    q, h = np.array([UPRIGHT, UPRIGHT]), np.array([[10.0, 10, 5], [10.0, 10, 2.5]])
    hm = heightmap_from_boxes((40, 20), c, q, h, tolerance=0.5)
    assert hm[:20, :].min() == 10
    assert hm[20:, :].max() == 5 and hm[20:, :].min() == 5
