"""The Execution Pack end to end: the robot places boxes, and unsafe operations are flagged."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from robobpp.core import Action, Box, ContainerSpec, EpisodeSpec, Placement
from robobpp.sim import make_setting
from robobpp.sim.execution import ExecutionPack, Layout
from robobpp.sim.physics.world import PALLET_HEIGHT_M
from robobpp.sim.planner import PlannerConfig

CONTAINER = ContainerSpec(134, 125, 100)


def _spec(boxes: list[Box], seed: int = 0) -> EpisodeSpec:
    return EpisodeSpec("handmade", "train", 0, tuple(boxes), CONTAINER, 7.0, seed)


def _run(pack: ExecutionPack, boxes: list[Box], actions: list[Action], seed: int = 0) -> list:
    pack.reset(_spec(boxes, seed))
    return [pack.apply(box, action, i) for i, (box, action) in enumerate(zip(boxes, actions, strict=True))]


def test_open_path_places_the_box_within_a_centimetre() -> None:
    pack = ExecutionPack()
    try:
        (outcome,) = _run(pack, [Box(40, 30, 20, 5.0)], [Action(50, 40, 1)])
        assert outcome.termination is None and outcome.placement is not None
        placed = outcome.placement
        assert abs(placed.x - 50) < 1 and abs(placed.y - 40) < 1 and abs(placed.z) < 1
        assert (placed.length, placed.width) == (30, 40)  # orientation 1 turns the box
        assert outcome.dangerous is False
        assert outcome.extra["plan_status"] in ("direct", "via", "planned")
        assert 1.0 < outcome.trajectory_length_m < 6.0
        assert 0 < outcome.extra["execution_time_s"] < pack.execution.safe_time_s
        assert outcome.static_stability is not None
        # Replay data: the TCP path in the container frame (cm), pick to release, at most 60 points.
        path = outcome.extra["tool_path_cm"]
        assert 10 <= len(path) <= 60 and all(len(pt) == 3 and type(pt[0]) is float for pt in path)
        pick = pack.layout.pick_box_pose(Box(40, 30, 20, 5.0))[0] * 100  # type: ignore[union-attr]
        assert np.allclose(path[0], pick + [0, 0, 10], atol=0.05)  # the grasp: top-face centre
        assert np.allclose(path[-1], [65, 60, 20 + pack.config.release_gap_cm], atol=0.05)  # turned box
        assert outcome.extra["poses"] and len(outcome.extra["poses"][0]) == 7
    finally:
        pack.close()


def test_a_wall_of_boxes_forces_a_longer_path() -> None:
    far = (Box(30, 30, 20, 3.0), Action(52, 5, 0))
    wall = [Box(134, 20, 90, 20.0)]
    pack = ExecutionPack()
    try:
        (alone,) = _run(pack, [far[0]], [far[1]])
        *_, behind = _run(pack, [*wall, far[0]], [Action(0, 100, 0), far[1]])
    finally:
        pack.close()
    assert behind.termination is None and behind.dangerous is False
    assert behind.trajectory_length_m > alone.trajectory_length_m + 0.3
    assert behind.extra["execution_time_s"] > alone.extra["execution_time_s"]


def test_enclosed_goal_ends_the_episode_as_a_failed_place_plan() -> None:
    # A slot on the floor behind a 95 cm wall on the robot's side: with its box 35 cm above the slot (the
    # reference's pre-place pose) the arm lies on the wall. The reference ends the episode there
    # ("Move_ee_to fail"), the box not placed and the operation not counted.
    boxes = [Box(134, 50, 95, 30.0), Box(20, 15, 10, 1.0)]
    actions = [Action(0, 75, 0), Action(57, 58, 0)]
    pack = ExecutionPack()
    try:
        _, outcome = _run(pack, boxes, actions)
        kept = pack.final_boxes()
    finally:
        pack.close()
    assert outcome.termination is not None and outcome.termination.reason == "place_plan_failed"
    assert "no_path:goal_invalid" in outcome.termination.detail
    assert outcome.placement is None and outcome.dangerous is None and len(kept) == 1
    # Physics version 3's rule: only dangerous, and the robot moves unchecked.
    pack = ExecutionPack(end_on_failed_place=False)
    try:
        _, outcome = _run(pack, boxes, actions)
    finally:
        pack.close()
    assert outcome.dangerous is True and outcome.placement is not None
    assert "no_path:goal_invalid" in outcome.extra["dangerous_reasons"]


def test_approximate_plans_accept_an_enclosed_goal_and_count_it_dangerous_once_the_search_would_overrun() -> (
    None
):
    # The same enclosed slot with the reference's planner rule: its search returns an approximate path (the
    # pre-place pose in collision), accepted; the robot stops short and the box is put at its target. The
    # operation is dangerous only from the placement where the reference's time limit (10 s + 1 s per placed
    # box) reaches its 15 s threshold, the sixth; then the robot moves unchecked as with the default rule.
    wall, slot = (Box(134, 50, 95, 30.0), Action(0, 75, 0)), (Box(20, 15, 10, 1.0), Action(57, 58, 0))
    fillers = [(Box(20, 20, 10, 1.0), Action(5 + 25 * i, 5, 0)) for i in range(4)]
    early = [wall, slot]
    late = [wall, *fillers, slot]
    pack = ExecutionPack(approximate_plans=True)
    try:
        outcomes = _run(pack, [b for b, _ in early], [a for _, a in early])
        wall_after = pack.final_boxes()[0]
        late_outcomes = _run(pack, [b for b, _ in late], [a for _, a in late])
    finally:
        pack.close()
    accepted = outcomes[1]
    assert accepted.termination is None and accepted.placement is not None
    assert accepted.dangerous is False and accepted.extra["plan_status"] == "approximate:goal_invalid"
    assert abs(accepted.placement.x - 57) < 1 and abs(accepted.placement.y - 58) < 1
    # Nothing was driven into the wall: it stands where it was placed.
    assert (
        abs(wall_after.actual.x - wall_after.planned.x) < 0.5
        and abs(wall_after.actual.y - wall_after.planned.y) < 0.5
    )
    overrun = late_outcomes[-1]
    assert [o.termination for o in late_outcomes[:-1]] == [None] * (len(late) - 1)
    # Not a failed place plan: the unchecked move goes through the wall (which may then collapse).
    assert overrun.termination is None or overrun.termination.reason == "collapse"
    assert overrun.dangerous is True and "no_path:goal_invalid" in overrun.extra["dangerous_reasons"]
    assert all(o.dangerous is False for o in late_outcomes[:-1])


def test_place_clearance_holds_the_carried_box_that_far_above_its_resting_place() -> None:
    # Released from the pre-place pose (descend=False), the tool path ends there: by default the TCP (the carried
    # box's top) 35 cm above the target's centre; with the reference's measured height, the box's bottom 37.5 cm
    # above where it will rest, whatever its height.
    box, action = Box(40, 30, 20, 5.0), Action(50, 40, 1)
    tops = {}
    for clearance in (0.0, 0.375):
        pack = ExecutionPack(descend=False, place_clearance_m=clearance)
        try:
            (outcome,) = _run(pack, [box], [action])
        finally:
            pack.close()
        assert outcome.termination is None and outcome.placement is not None
        tops[clearance] = outcome.extra["tool_path_cm"][-1][2]
    assert tops[0.0] == pytest.approx(10 + 35, abs=0.5)
    assert tops[0.375] == pytest.approx(20 + 37.5, abs=0.5)


def test_unreachable_goal_ends_the_episode() -> None:
    layout = Layout(CONTAINER, floor_z=-PALLET_HEIGHT_M, standoff=3.0)  # pallet out of the arm's reach
    pack = ExecutionPack(layout=layout)
    try:
        (outcome,) = _run(pack, [Box(30, 30, 20, 3.0)], [Action(10, 10, 0)])
    finally:
        pack.close()
    assert outcome.termination is not None and outcome.termination.reason == "place_plan_failed"
    assert "unreachable" in outcome.termination.detail and outcome.placement is None
    pack = ExecutionPack(layout=layout, end_on_failed_place=False)
    try:
        (outcome,) = _run(pack, [Box(30, 30, 20, 3.0)], [Action(10, 10, 0)])
    finally:
        pack.close()
    assert outcome.dangerous is True and "unreachable" in outcome.extra["dangerous_reasons"]
    assert outcome.placement is not None and outcome.trajectory_length_m > 0


def test_pre_place_pose_comes_down_where_the_arm_cannot_reach_35_cm_above() -> None:
    # The far top corner of the 1.7 m Diverse stack: 35 cm above it is out of reach, the placement is not.
    diverse = ContainerSpec(120, 100, 170)
    layout = Layout(diverse, floor_z=-PALLET_HEIGHT_M)
    top = np.array([0.10, 0.10, 1.70])
    assert layout.place_ik(top + [0, 0, 0.35], 0, layout.home) is None
    assert layout.place_ik(top + [0, 0, 0.25], 0, layout.home) is not None
    boxes = (Box(20, 20, 80, 5.0), Box(20, 20, 80, 5.0), Box(20, 20, 10, 1.0))  # two posts and a lid
    pack = ExecutionPack()
    try:
        pack.reset(EpisodeSpec("handmade", "train", 0, boxes, diverse, 4.0, 0))
        outcomes = [pack.apply(b, Action(0, 0, 0), i) for i, b in enumerate(boxes)]
    finally:
        pack.close()
    assert all(o.termination is None and o.placement is not None for o in outcomes)
    assert outcomes[-1].placement.z == pytest.approx(160, abs=1)  # type: ignore[union-attr]


def test_the_third_dangerous_operation_ends_the_episode_without_its_box() -> None:
    # Every operation takes over 1 cs: each is dangerous ("slow"); the third ends the episode, and its box
    # is not counted (the reference drops it from its packed boxes).
    boxes = [Box(30, 30, 20, 3.0), Box(30, 30, 20, 3.0), Box(30, 30, 20, 3.0), Box(30, 30, 20, 3.0)]
    actions = [Action(0, 0, 0), Action(40, 0, 0), Action(80, 0, 0), Action(0, 40, 0)]
    pack = ExecutionPack(safe_time_s=0.01)
    try:
        outcomes = _run(pack, boxes[:3], actions[:3])
        kept = pack.final_boxes()
    finally:
        pack.close()
    assert all(o.dangerous and "slow" in o.extra["dangerous_reasons"] for o in outcomes)
    assert [o.termination for o in outcomes[:2]] == [None, None]
    assert outcomes[2].termination is not None and outcomes[2].termination.reason == "dangerous_operations"
    assert outcomes[2].placement is None and [f.planned.index for f in kept] == [0, 1]
    unlimited = ExecutionPack(safe_time_s=0.01, dangerous_limit=0)
    try:
        outcomes = _run(unlimited, boxes, actions)
    finally:
        unlimited.close()
    assert all(o.termination is None and o.dangerous for o in outcomes)


def test_box_over_suction_capacity_is_a_failed_grasp() -> None:
    heavy = Box(20, 20, 10, 12.0)  # 260 kg/m² × 0.04 m² = 10.4 kg
    light = Box(20, 20, 10, 10.0)
    pack = ExecutionPack()
    try:
        over, under = _run(pack, [heavy, light], [Action(0, 0, 0), Action(40, 0, 0)])
    finally:
        pack.close()
    assert over.dangerous is True and over.extra["failed_grasp"] is True
    assert "failed_grasp" in over.extra["dangerous_reasons"]
    assert under.extra["failed_grasp"] is False
    # Failed grasps are dangerous but do not count towards the dangerous-operation limit.
    pack = ExecutionPack()
    try:
        outcomes = _run(pack, [heavy] * 3, [Action(0, 0, 0), Action(40, 0, 0), Action(80, 0, 0)])
    finally:
        pack.close()
    assert all(o.dangerous and o.termination is None for o in outcomes)
    strict = ExecutionPack(end_on_failed_grasp=True)
    try:
        (ended,) = _run(strict, [heavy], [Action(0, 0, 0)])
    finally:
        strict.close()
    assert ended.termination is not None and ended.termination.reason == "failed_grasp"
    assert ended.placement is None and ended.dangerous is True


def test_same_seed_same_trajectory() -> None:
    boxes = [Box(40, 30, 20, 5.0), Box(30, 30, 30, 4.0), Box(50, 20, 25, 6.0)]
    actions = [Action(0, 0, 0), Action(40, 0, 0), Action(0, 30, 1)]
    runs: list[list[object]] = []
    for _ in range(2):
        pack = ExecutionPack()
        try:
            outcomes = _run(pack, boxes, actions, seed=11)
            runs.append(
                [
                    (o.trajectory_length_m, o.extra["execution_time_s"], o.extra["planner_seed"], o.placement)
                    for o in outcomes
                ]
            )
            operation = pack.last_operation
            assert operation is not None and operation.trajectory is not None
            runs[-1].append(operation.trajectory.waypoints.tobytes())
        finally:
            pack.close()
    assert runs[0] == runs[1]


def test_make_setting_and_option_checks() -> None:
    pack = make_setting("execution", safe_time_s=5.0, mode="full")
    try:
        assert isinstance(pack, ExecutionPack) and pack.execution.safe_time_s == 5.0
        assert pack.config.mode == "full"
    finally:
        pack.close()
    with pytest.raises(TypeError, match="unknown Execution Pack option"):
        ExecutionPack(speed_of_light=1.0)
    with pytest.raises(ValueError, match="safe_time_s"):
        ExecutionPack(safe_time_s=float("nan"))
    with pytest.raises(ValueError, match="another container"):
        ExecutionPack(layout=Layout(ContainerSpec(10, 10, 10))).reset(_spec([Box(1, 1, 1)]))


def test_apply_before_reset_is_refused() -> None:
    with pytest.raises(RuntimeError, match="reset"):
        ExecutionPack().apply(Box(10, 10, 10), Action(0, 0, 0), 0)
    assert np.isfinite(Layout(CONTAINER).home).all()


A, B = Box(29.1, 17.4, 21.5, 6.016), Box(30.6, 15.8, 27.7, 6.405)
#: DBL's first nine placements on repetitive train group 0: boxes of 17.4 and 15.8 cm in rows on the 1 cm
#: grid, so slots overlap their neighbours by up to 4 mm. Box 8 goes in beside box 5, 4 mm into it.
DBL_ROWS = [
    (A, 0, 0),
    (B, 0, 17),
    (B, 29, 0),
    (B, 0, 33),
    (A, 31, 16),
    (A, 0, 49),
    (B, 60, 0),
    (B, 31, 33),
    (B, 0, 66),
]


def _dbl_rows(**options: Any) -> tuple[list, list[float]]:
    """Outcomes, and how far (cm) each box stands from its target at the end."""
    pack = ExecutionPack(**options)
    try:
        outcomes = _run(pack, [b for b, _, _ in DBL_ROWS], [Action(x, y, 0) for _, x, y in DBL_ROWS])
        final = pack.final_boxes()
    finally:
        pack.close()
    drift = [float(np.hypot(f.actual.x - f.planned.x, f.actual.y - f.planned.y)) for f in final]
    return outcomes, drift


def test_slots_overlapping_neighbours_by_millimetres_are_planned_and_do_not_shove_them() -> None:
    # The planner alone (a full-size carried box, the old 1 cm tolerance): Bullet's persistent contact
    # manifolds reported box 8's 4 mm sideways overlap as 13 mm deep, "no_path", and the unchecked
    # move then pushed the row behind the slot by 2-3 cm.
    outcomes, _ = _dbl_rows(carried_margin_cm=0.0, planner=PlannerConfig(box_tolerance_m=0.01))
    assert all(o.extra["plan_status"] in ("direct", "via", "planned") for o in outcomes)
    # With the default margin the robot delivers every box without shoving the pile: what is left is
    # the release's overlap resolution, as in the Physics Pack.
    outcomes, drift = _dbl_rows()
    assert not any(o.dangerous or o.collapsed for o in outcomes)
    assert max(drift) < 1.0, drift


def test_the_arm_has_left_before_the_released_box_settles() -> None:
    """A plank with two thirds of its footprint beyond its post tips off the post in the Physics Pack; the
    tool waiting at the release pose used to prop it up (the plank then stayed up on the post, z = 40)."""
    support, plank = Box(20, 20, 40, 5.0), Box(40, 20, 10, 5.0)
    pack = ExecutionPack()
    try:
        _, outcome = _run(pack, [support, plank], [Action(30, 30, 0), Action(36, 30, 0)])
    finally:
        pack.close()
    # Off the post: it lands flat beside it or, with physics version 3's friction anchors holding its lower
    # end, on its end (bottom at the deck either way; "collapsed" is the horizontal rule, which a plank
    # standing beside its post may not meet).
    assert outcome.placement is not None and outcome.placement.z < 20


@pytest.mark.parametrize("setting", ["physics", "execution"])
def test_too_high_allows_the_heightmap_rounding_in_both_packs(setting: str) -> None:
    """The observed heightmap is rounded to 1 mm, so a top up to 0.5 mm over the container passes."""
    fits, over = Box(30, 30, 100.04, 2.0), Box(30, 30, 100.1, 2.0)
    pack = make_setting(setting)
    try:
        pack.reset(_spec([fits, over]))
        assert pack.config.too_high_slack_cm == pytest.approx(0.05)  # type: ignore[attr-defined]
        assert isinstance(pack.target_placement(fits, Action(0, 0, 0), 0), Placement)  # type: ignore[attr-defined]
        refused = pack.target_placement(over, Action(0, 0, 0), 0)  # type: ignore[attr-defined]
        assert refused.reason == "too_high"
    finally:
        pack.close()
