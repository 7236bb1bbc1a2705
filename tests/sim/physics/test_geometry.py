"""Heights under a footprint from actual (moved, tilted) boxes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robobpp.core import Placement
from robobpp.sim.physics.geometry import aabbs, clear_shift, heightmap_from_boxes, surface_height

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


def _bounds(*boxes: tuple[float, float, float, float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    arr = np.array(boxes, dtype=float).reshape(-1, 6)
    return arr[:, :3], arr[:, 3:]


def test_clear_shift_moves_the_box_out_of_a_shallow_neighbour() -> None:
    """A neighbour reaching 4 mm into the footprint: the box is shifted away by 4 mm + the clearance."""
    lo, hi = _bounds((0, 0, 0, 27.4, 30, 20))  # neighbour occupies x < 27.4
    planned = Placement(27, 0, 0, 20, 20, 10, 0, 0)
    dx, dy = clear_shift(lo, hi, planned, 0.2, 0.5, 0.01)
    assert (dx, dy) == pytest.approx((0.41, 0.0))
    # On the other side it is shifted the other way; along y the same.
    lo, hi = _bounds((46.8, 0, 0, 70, 30, 20))
    assert clear_shift(lo, hi, planned, 0.2, 0.5, 0.01) == pytest.approx((-0.21, 0.0))
    lo, hi = _bounds((27, 19.7, 0, 47, 40, 20))
    assert clear_shift(lo, hi, planned, 0.2, 0.5, 0.01) == pytest.approx((0.0, -0.31))


def test_clear_shift_leaves_what_it_cannot_or_need_not_clear() -> None:
    planned = Placement(27, 0, 0, 20, 20, 10, 0, 0)
    # Nothing in the way; a box below the release height (what it rests on) is not in the way either.
    assert clear_shift(*_bounds((0, 0, 0, 10, 10, 5)), planned, 0.2, 0.5, 0.01) == (0.0, 0.0)
    assert clear_shift(*_bounds((20, 0, -10, 50, 30, 0)), planned, 0.2, 0.5, 0.01) == (0.0, 0.0)
    # Deeper than the tolerance, or squeezed from both sides along x: released as chosen.
    assert clear_shift(*_bounds((0, 0, 0, 28, 30, 20)), planned, 0.2, 0.5, 0.01) == (0.0, 0.0)
    both = _bounds((0, 0, 0, 27.3, 30, 20), (46.8, 0, 0, 70, 30, 20))
    assert clear_shift(*both, planned, 0.2, 0.5, 0.01) == (0.0, 0.0)
    # A shift that would run into another box is not taken.
    blocked = _bounds((0, 0, 0, 27.3, 30, 20), (47.1, 0, 0, 47.3, 30, 20))
    assert clear_shift(*blocked, planned, 0.2, 0.5, 0.01) == (0.0, 0.0)
