import pytest

from robobpp.core import ContainerSpec, FinalBox, Placement, static_stability
from robobpp.scoring import metrics as M

C = ContainerSpec(10, 10, 10)


def final(p: Placement, actual: Placement | None = None, in_place: bool = True) -> FinalBox:
    return FinalBox(p, actual or p, in_place)


def test_space_utilization_counts_only_boxes_still_in_place():
    a = Placement(0, 0, 0, 5, 10, 2, 0, 0)  # 100 cm³
    b = Placement(5, 0, 0, 5, 5, 4, 0, 1)  # 100 cm³
    assert M.space_utilization([final(a), final(b)], C) == pytest.approx(200 / 1000)
    assert M.space_utilization([final(a), final(b, in_place=False)], C) == pytest.approx(100 / 1000)


def test_occupancy_against_hand_computed_heightmap():
    # A 2 cm slab over half the floor, then a 1×1×1 cube on top at its corner and a tall post elsewhere.
    slab = Placement(0, 0, 0, 5, 10, 2, 0, 0)  # 100 cm³, raises 50 cells to 2
    cube = Placement(0, 0, 2, 1, 1, 1, 0, 1)  # 1 cm³, raises 1 cell to 3
    post = Placement(9, 9, 0, 1, 1, 6, 0, 2)  # 6 cm³, raises 1 cell to 6
    under = 49 * 2 + 3 + 6
    assert M.occupancy([final(slab), final(cube), final(post)], C) == pytest.approx(107 / under)


def test_occupancy_uses_actual_positions():
    planned = Placement(0, 0, 4, 2, 2, 2, 0, 0)  # a box meant to sit high (unsupported)
    fallen = Placement(0, 0, 0, 2, 2, 2, 0, 0)
    assert M.occupancy([final(planned, fallen)], C) == pytest.approx(1.0)


def test_occupancy_ignores_boxes_that_fell_off_the_pallet():
    box = Placement(0, 0, 0, 2, 2, 2, 0, 0)
    fell = Placement(12, 3, -15, 2, 2, 2, 0, 1)  # planned inside, now on the ground beside the pallet
    assert M.occupancy(
        [final(box), final(Placement(4, 4, 0, 2, 2, 2, 0, 1), fell, False)], C
    ) == pytest.approx(1.0)


def test_local_stability_is_mean_displacement_in_metres():
    p1 = Placement(0, 0, 0, 2, 2, 2, 0, 0)
    a1 = Placement(3, 4, 0, 2, 2, 2, 0, 0)  # moved 5 cm
    p2 = Placement(5, 5, 0, 2, 2, 2, 0, 1)
    assert M.local_stability_m([final(p1, a1), final(p2)]) == pytest.approx((0.05 + 0.0) / 2)


@pytest.mark.parametrize(
    ("v", "w", "expected"),
    [
        (0.0, 0.0, 1.0),
        (1.0, 1.0, 0.0),
        (5.0, 0.0, 0.5),
        (0.01, 0.001, 0.5 * (1 - 0.01**0.4) + 0.5 * (1 - 0.001**0.3)),
    ],
)
def test_static_stability_formula(v, w, expected):
    assert static_stability(v, w) == pytest.approx(expected)


def test_aggregate_means_and_pooled_ratios():
    episodes = [
        {
            "space_utilization": 0.5,
            "decision_time": 0.1,
            "placements_collapsed": 1,
            "placements_attempted": 10,
            "operations": 10,
            "operations_dangerous": 0,
        },
        {
            "space_utilization": 0.7,
            "decision_time": None,
            "placements_collapsed": 0,
            "placements_attempted": 30,
            "operations": 30,
            "operations_dangerous": 3,
        },
    ]
    out = M.aggregate(episodes, "execution")
    assert out["space_utilization"] == pytest.approx(0.6)
    assert out["decision_time"] == pytest.approx(0.1)  # missing values are skipped, not zeros
    assert out["collapsed_placement"] == pytest.approx(1 / 40)  # pooled, not mean of 0.1 and 0
    assert out["dangerous_operation"] == pytest.approx(3 / 40)
    assert "trajectory_length" in out and "local_stability" not in M.aggregate(episodes, "math")
