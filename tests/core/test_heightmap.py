import numpy as np
import pytest

from robobpp.core import Box, ContainerSpec, ContainerState, Placement, drop_height_map, footprint_cells
from robobpp.core.feasibility import TOLERANCE_CM
from robobpp.core.heightmap import window_all


def brute_force_drop(hm: np.ndarray, lc: int, wc: int) -> np.ndarray:
    nx, ny = hm.shape[0] - lc + 1, hm.shape[1] - wc + 1
    out = np.zeros((max(nx, 0), max(ny, 0)))
    for i in range(nx):
        for j in range(ny):
            out[i, j] = hm[i : i + lc, j : j + wc].max()
    return out


@pytest.mark.parametrize("size", [(1, 1), (2, 3), (5, 4), (7, 7), (8, 1), (12, 9)])
def test_drop_height_map_matches_brute_force(size):
    rng = np.random.default_rng(sum(size))
    hm = rng.integers(0, 30, size=(12, 9)).astype(float)
    np.testing.assert_array_equal(drop_height_map(hm, *size), brute_force_drop(hm, *size))


def _random_heightmaps(rng: np.random.Generator, shape: tuple[int, int], height: float):
    """Heightmaps of every kind a policy observes: Math Pack piles of 1 mm-resolution boxes (summed float
    tops), physical ones rounded to 1 mm, and unrounded floats."""
    state = ContainerState(ContainerSpec(shape[0], shape[1], height))
    for i in range(40):
        length, width = (
            float(v) for v in np.minimum(np.round(rng.uniform(0.05, 0.6, 2) * shape + 0.5, 1), shape)
        )
        x, y = (float(v) for v in rng.integers(0, (int(shape[0] - length + 1), int(shape[1] - width + 1))))
        box = Box(length, width, float(np.round(rng.uniform(0.5, 9), 1)))
        placement = state.drop(box, x, y, 0, i)
        if placement.top <= height + TOLERANCE_CM:
            state.add(placement)
    yield state.heightmap.copy()
    yield np.round(rng.uniform(0, height, shape) / 0.1) * 0.1
    yield rng.uniform(0, height, shape)
    yield np.zeros(shape)


def test_window_all_below_the_limit_is_exactly_the_resting_height_test():
    """``window_all(heightmap + height <= limit, ...)``, how the feasibility mask is computed, answers what
    ``drop_height_map(...) + height <= limit`` answers, position by position, on integer, 1 mm and unrounded
    heightmaps, non-integer boxes, and boxes whose top meets the limit exactly."""
    rng = np.random.default_rng(40)
    checked, fitting = 0, 0
    for _ in range(30):
        shape = (int(rng.integers(1, 30)), int(rng.integers(1, 30)))
        container_height = float(rng.choice([10.0, 20.0, 33.3]))
        limit = container_height + TOLERANCE_CM
        for hm in _random_heightmaps(rng, shape, container_height):
            for _ in range(8):
                length, width = (float(v) for v in np.round(rng.uniform(0.5, 32, 2), 1))
                # free heights, and ones that put the top exactly on the limit above some cell
                cell = float(hm.flat[rng.integers(hm.size)])
                for height in (
                    float(np.round(rng.uniform(0.1, 25), 1)),
                    container_height - cell,
                    limit - cell,
                ):
                    expected = drop_height_map(hm, length, width) + height <= limit
                    got = window_all(hm + height <= limit, length, width)
                    assert got.dtype == bool and got.shape == expected.shape
                    np.testing.assert_array_equal(got, expected)
                    checked, fitting = checked + expected.size, fitting + int(expected.sum())
    assert checked > 10_000 and 0.2 < fitting / checked < 0.8  # both answers, often


def test_box_larger_than_container_has_no_position():
    assert drop_height_map(np.zeros((10, 10)), 11, 3).size == 0


def test_non_integer_footprint_covers_every_touched_cell():
    # 2.5 cm wide at x = 0.5 touches cells 0, 1, 2
    assert footprint_cells(0.5, 0.0, 2.5, 1.0, (10, 10)) == (slice(0, 3), slice(0, 1))
    # exactly 3 cm at x = 2 touches cells 2, 3, 4 only
    assert footprint_cells(2.0, 0.0, 3.0, 1.0, (10, 10)) == (slice(2, 5), slice(0, 1))


def test_drop_rests_on_highest_cell_under_footprint_even_with_overhang():
    state = ContainerState(ContainerSpec(10, 10, 10))
    state.add(Placement(0, 0, 0, 4, 10, 3, 0, 0))  # a 3 cm slab on the back 4 cm
    box = Box(6, 2, 2)
    half_over = state.drop(box, 2, 0, 0, index=1)  # footprint x 2..8 overhangs the slab
    assert half_over.z == 3
    beside = state.drop(box, 4, 0, 0, index=1)  # x 4..10 misses it
    assert beside.z == 0


def test_heightmap_is_max_of_tops_and_volume_under_it():
    state = ContainerState(ContainerSpec(4, 4, 10))
    state.add(Placement(0, 0, 0, 2, 2, 5, 0, 0))
    state.add(Placement(0, 0, 5, 4, 1, 1, 0, 1))  # thin bar on top, overhanging
    assert state.heightmap[0, 0] == 6 and state.heightmap[3, 0] == 6
    assert state.heightmap[1, 1] == 5 and state.heightmap[3, 3] == 0
    # 4 cells in row y=0 at 6, cells (0,1),(1,1) at 5
    assert state.volume_under_heightmap() == 4 * 6 + 2 * 5


def test_rotated_box_swaps_length_and_width():
    assert Box(3, 2, 1).dims(1) == (2, 3, 1)
    with pytest.raises(ValueError, match="orientation"):
        Box(3, 2, 1).dims(2)


@pytest.mark.parametrize("bad", [0, -1, float("nan"), float("inf")])
def test_box_refuses_degenerate_sizes(bad):
    with pytest.raises(ValueError, match="finite number > 0"):
        Box(bad, 1, 1)
