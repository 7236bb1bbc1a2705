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


def test_occupancy_is_the_mean_over_placements_against_hand_computed_heightmaps():
    slab = Placement(0, 0, 0, 5, 10, 2, 0, 0)  # 100 cm³ over 50 cells, 2 cm high: no gap under it
    high = Placement(5, 0, 4, 2, 2, 2, 0, 1)  # 8 cm³ planned 4 cm up: 4 cells raised to 6
    post = Placement(9, 9, 0, 1, 1, 6, 0, 2)  # 6 cm³, one cell to 6
    after = [100 / 100, 108 / (100 + 4 * 6), 114 / (100 + 4 * 6 + 6)]
    assert M.occupancy([slab, high, post], C) == pytest.approx(sum(after) / 3)
    # Not the final heightmap's figure alone (version 1's reading), and the order matters.
    assert M.occupancy([slab, high, post], C) != pytest.approx(after[-1])
    assert M.occupancy([high, slab, post], C) == pytest.approx((8 / 24 + 108 / 124 + 114 / 130) / 3)
    assert M.occupancy([], C) is None


def test_occupancy_counts_a_box_planned_over_a_gap_as_the_gap_under_it():
    high = Placement(0, 0, 4, 2, 2, 2, 0, 0)  # planned 4 cm up (an unsupported plan)
    assert M.occupancy([high], C) == pytest.approx(8 / (4 * 6))


def test_local_stability_is_the_mean_horizontal_offset_dx_plus_dy_in_metres():
    p1 = Placement(0, 0, 0, 2, 2, 2, 0, 0)
    a1 = Placement(3, 4, 0, 2, 2, 2, 0, 0)  # moved 3 cm along x and 4 along y: 7 cm, not the 5 cm diagonal
    p2 = Placement(5, 5, 0, 2, 2, 2, 0, 1)
    a2 = Placement(5, 5, -15, 2, 2, 2, 0, 1)  # sank (fell through a gap): height is left out
    assert M.local_stability_m([final(p1, a1), final(p2, a2)]) == pytest.approx((0.07 + 0.0) / 2)
    assert M.local_stability_m([]) is None


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
    episodes: list[dict[str, float | None]] = [
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


def test_math_pack_keeps_the_volumes_occupancy_would_replay_to_the_bit():
    """Math Pack hands Occupancy the volume under its heightmap after each placement instead of a replay of the
    plan; on real episodes the figure is the replay's, bit for bit (the same heightmaps summed)."""
    import numpy as np

    from robobpp.datasets.sampling import GroupDraw
    from robobpp.episode import Episode
    from robobpp.policies.random_policy import RandomPolicy

    draw = GroupDraw("repetitive", "train", 0)
    for group in range(4):
        episode = Episode(draw(group), "math")
        policy = RandomPolicy(seed=group)
        policy.reset(episode.info)
        while not episode.done:
            episode.step(policy.act(episode.observe()), decision_time=0.0)
        plan = episode.setting.plan()
        kept = episode.setting.under_volumes()
        assert kept is not None and len(kept) == len(plan) > 5
        assert M.occupancy(plan, episode.spec.container, kept) == M.occupancy(plan, episode.spec.container)
        assert episode.result("random").metrics["occupancy"] == M.occupancy(plan, episode.spec.container)
        assert np.all(np.diff(kept) > 0)  # every placement raised the pile
