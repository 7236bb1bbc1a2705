"""EMS module: the difference process agrees with a brute-force enumeration of maximal spaces."""

from __future__ import annotations

import numpy as np
import pytest

from robobpp.policies.ems import EmsTracker, empty_container, ems_from_heightmap, height_rectangles


def brute_force_ems(hm: np.ndarray, height: float) -> list[tuple[int, int, int, int, float]]:
    """Every rectangle, every level: keep the empty, x/y-maximal ones whose floor is their highest cell."""
    nx, ny = hm.shape
    out = set()
    for z in sorted({0.0, *map(float, np.unique(hm))}):
        if z >= height:
            continue
        free = hm <= z
        for x0 in range(nx):
            for x1 in range(x0 + 1, nx + 1):
                for y0 in range(ny):
                    for y1 in range(y0 + 1, ny + 1):
                        if not free[x0:x1, y0:y1].all() or hm[x0:x1, y0:y1].max() != z:
                            continue
                        grow = [
                            x0 > 0 and free[x0 - 1, y0:y1].all(),
                            x1 < nx and free[x1, y0:y1].all(),
                            y0 > 0 and free[x0:x1, y0 - 1].all(),
                            y1 < ny and free[x0:x1, y1].all(),
                        ]
                        if not any(grow):
                            out.add((x0, y0, x1, y1, z))
    return sorted(out)


def test_empty_container_is_one_space() -> None:
    assert empty_container((4, 3), 5.0).as_tuples() == [(0, 0, 4, 3, 0.0)]
    assert ems_from_heightmap(np.zeros((4, 3)), 5.0).as_tuples() == [(0, 0, 4, 3, 0.0)]


def test_one_box_in_the_corner_leaves_three_spaces() -> None:
    hm = np.zeros((4, 4))
    hm[:2, :2] = 3.0  # a 2×2×3 box in the back-left corner of a 4×4×10 container
    assert ems_from_heightmap(hm, 10.0).as_tuples() == [
        (0, 0, 4, 4, 3.0),  # above the box, the whole footprint
        (0, 2, 4, 4, 0.0),  # in front of it, on the floor
        (2, 0, 4, 4, 0.0),  # right of it, on the floor
    ]


def test_a_box_reaching_the_top_leaves_no_space_above() -> None:
    hm = np.zeros((4, 4))
    hm[:2, :] = 10.0
    assert ems_from_heightmap(hm, 10.0).as_tuples() == [(2, 0, 4, 4, 0.0)]


@pytest.mark.parametrize("seed", range(12))
def test_matches_brute_force_on_random_terrain(seed: int) -> None:
    rng = np.random.default_rng(seed)
    hm = np.zeros((6, 5))
    for _ in range(rng.integers(1, 6)):  # drop a few random boxes, Math Pack style
        lc, wc = rng.integers(1, 4, size=2)
        x, y = rng.integers(0, 6 - lc + 1), rng.integers(0, 5 - wc + 1)
        hm[x : x + lc, y : y + wc] = hm[x : x + lc, y : y + wc].max() + rng.integers(1, 4)
    assert ems_from_heightmap(hm, 12.0).as_tuples() == brute_force_ems(hm, 12.0)


def test_height_rectangles_rebuild_the_heightmap() -> None:
    rng = np.random.default_rng(3)
    hm = rng.integers(0, 3, size=(7, 6)).astype(float)
    rebuilt = np.zeros_like(hm)
    for i0, j0, i1, j1, h in height_rectangles(hm):
        assert (rebuilt[i0:i1, j0:j1] == 0).all()  # rectangles do not overlap
        rebuilt[i0:i1, j0:j1] = h
    np.testing.assert_array_equal(rebuilt, hm)


def test_tracker_is_incremental_when_the_heightmap_rises_and_rebuilds_when_it_drops() -> None:
    rng = np.random.default_rng(5)
    tracker = EmsTracker()
    hm = np.zeros((8, 7))
    tracker.update(hm, 20.0)
    for _ in range(6):
        lc, wc = rng.integers(1, 4, size=2)
        x, y = rng.integers(0, 8 - lc + 1), rng.integers(0, 7 - wc + 1)
        hm[x : x + lc, y : y + wc] = hm[x : x + lc, y : y + wc].max() + rng.integers(1, 4)
        assert tracker.update(hm, 20.0).as_tuples() == ems_from_heightmap(hm, 20.0).as_tuples()
    assert tracker.rebuilds == 1
    hm[hm > 0] -= 0.5  # physics: things settled lower
    assert tracker.update(hm, 20.0).as_tuples() == ems_from_heightmap(hm, 20.0).as_tuples()
    assert tracker.rebuilds == 2
