"""The feasible grid kept up to date box after box (``FeasibleGrids``, the Gym env's mask) is the grid computed
afresh (``feasible_grid``), at every step of real and adversarial episodes."""

import numpy as np
import pytest

from robobpp.core import Box, ContainerSpec, ContainerState
from robobpp.core.feasibility import TOLERANCE_CM
from robobpp.core.feasible_grid import FeasibleGrids, feasible_grid, orientation_fits
from robobpp.core.heightmap import drop_height_map, highest_base, window_all, windows_all


class _Counting(FeasibleGrids):
    """Counts the grids computed afresh (the rest were caught up)."""

    computed = 0
    started_empty = 0

    def _compute(self, state, box):
        self.computed += 1
        return super()._compute(state, box)

    def _on_empty(self, state, box):
        self.started_empty += 1
        return super()._on_empty(state, box)


def _play(state: ContainerState, boxes: list[Box], rng: np.random.Generator, grids: FeasibleGrids) -> int:
    """Place ``boxes`` at random feasible positions, checking the kept grid against a fresh one before each;
    returns how many grids were compared."""
    compared = 0
    for index, box in enumerate(boxes):
        kept = grids(state, box)
        fresh = feasible_grid(state.heightmap, box, state.spec)
        np.testing.assert_array_equal(kept, fresh)
        compared += 1
        options = np.argwhere(fresh)
        if len(options) == 0:
            continue  # this one fits nowhere; the next may
        x, y, orientation = (int(v) for v in options[rng.integers(len(options))])
        placement = state.drop(box, float(x), float(y), orientation, index)
        assert placement.top <= state.spec.height + TOLERANCE_CM  # the grid admitted it: it fits
        state.add(placement)
    return compared


@pytest.mark.parametrize("seed", range(6))
def test_kept_grid_equals_a_fresh_one_at_every_step(seed):
    """Runs of equal boxes (caught up from the state's raises), a few sizes coming back (kept per size), sizes
    that exceed the container in one orientation, tops that meet the limit exactly, and new episodes on the same
    instance (a new state: recomputed)."""
    rng = np.random.default_rng(seed)
    container = ContainerSpec(30, 24, 20)
    sizes = [
        Box(6, 4, 5),
        Box(7.5, 3.2, 4.1),
        Box(26, 25, 2),  # turned, too long for the container
        Box(5, 5, 10),
        Box(3, 3, 20 - 10 + TOLERANCE_CM),
        Box(4, 4, 21),  # taller than the container: nowhere
    ]
    grids = _Counting(container, sizes=3)  # fewer kept sizes than come back: some are dropped and recomputed
    compared = 0
    for _ in range(3):
        boxes = [sizes[int(i)] for i in np.repeat(rng.integers(0, len(sizes), 12), rng.integers(1, 6, 12))]
        compared += _play(ContainerState(container), boxes, rng, grids)
    assert compared > 60
    # every way taken: recomputed, started from the empty container, and (mostly) caught up
    assert grids.computed >= 1 and grids.started_empty >= 3
    assert grids.computed + grids.started_empty < compared / 3


def test_a_long_run_since_the_last_box_of_a_size_is_recomputed_and_still_exact():
    rng = np.random.default_rng(7)
    container = ContainerSpec(40, 40, 30)
    a, b = Box(5, 4, 3), Box(2, 2, 1)
    boxes = [a] + [b] * (FeasibleGrids.MAX_CATCH_UP + 5) + [a, a]
    grids = _Counting(container)
    assert _play(ContainerState(container), boxes, rng, grids) == len(boxes)
    # a and b start from the empty container; a again after too many raises is recomputed
    assert (grids.started_empty, grids.computed) == (2, 1)


def test_a_heightmap_replaced_on_the_same_state_is_not_caught_up_from_stale_raises():
    container = ContainerSpec(10, 10, 10)
    state = ContainerState(container)
    grids = FeasibleGrids(container)
    box = Box(2, 2, 5)
    assert np.all(grids(state, box)[:9, :9, :])
    state.heightmap = np.full(
        container.grid_shape, 6.0
    )  # as a physical setting rebuilds it: no raise recorded
    assert not grids(state, box).any()


def test_the_grid_is_inside_and_below_the_top_exactly():
    """Every admitted position keeps the box inside and its top within the limit; every other in-bounds
    position does not (the resting heights, computed the slow way, agree)."""
    rng = np.random.default_rng(3)
    container = ContainerSpec(20, 15, 12)
    hm = np.round(rng.uniform(0, 10, container.grid_shape), 1)
    box = Box(4.5, 3, 2.2)
    grid = feasible_grid(hm, box, container)
    for orientation in (0, 1):
        length, width, height = box.dims(orientation)
        z = drop_height_map(hm, length, width)
        expected = np.zeros(container.grid_shape, bool)
        expected[: z.shape[0], : z.shape[1]] = z + height <= container.height + TOLERANCE_CM
        np.testing.assert_array_equal(grid[:, :, orientation], expected)
    assert 0 < grid.mean() < 1


def test_orientation_fits_skips_an_orientation_that_cannot_fit_at_all():
    container = ContainerSpec(30, 10, 10)
    fits = orientation_fits(np.zeros(container.grid_shape), Box(20, 5, 3), container)
    assert [o for o, _, _ in fits] == [0]  # turned, 20 cm do not go into 10


def test_windows_all_shares_work_and_answers_as_one_window_at_a_time():
    rng = np.random.default_rng(11)
    for i in range(30):
        # mostly True, and every third one all True (nothing in the way: answered without sliding)
        cells = rng.random((int(rng.integers(1, 40)), int(rng.integers(1, 40)))) < (0.9 if i % 3 else 1.0)
        footprints = [(float(a), float(b)) for a, b in np.round(rng.uniform(0.5, 45, (3, 2)), 1)]
        for got, (length, width) in zip(windows_all(cells, footprints), footprints, strict=True):
            alone = window_all(cells, length, width)
            assert got.shape == alone.shape
            np.testing.assert_array_equal(got, alone)
            expected = drop_height_map((~cells).astype(float), length, width) == 0
            np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("height", [0.1, 2.2, 3.3, 15.3, 7.0 / 3.0])
@pytest.mark.parametrize("limit", [10.0, 33.3 + TOLERANCE_CM, 120.0 + TOLERANCE_CM])
def test_highest_base_is_exactly_the_addition_test(height, limit):
    base = highest_base(height, limit)
    assert base + height <= limit
    assert np.nextafter(base, np.inf) + height > limit
    near = base + np.arange(-50, 51) * np.spacing(base)
    np.testing.assert_array_equal(near <= base, near + height <= limit)
