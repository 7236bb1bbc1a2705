"""OMPL planning in the private planning world: walls force detours, seeds reproduce paths."""

from __future__ import annotations

import numpy as np
import pytest

from robobpp.core import ContainerSpec
from robobpp.sim.execution import Layout
from robobpp.sim.physics.world import PALLET_HEIGHT_M
from robobpp.sim.planner import MotionPlanner, PlannerConfig, PlanningWorld, densify
from robobpp.sim.robot import path_length, tcp_pose

LAYOUT = Layout(ContainerSpec(134, 125, 100), floor_z=-PALLET_HEIGHT_M)
WALL = ((-0.15, 1.2, 0.45), (0.05, 0.9, 0.6))  # between the pick station and the pallet, 1.05 m tall


def _endpoints() -> tuple[np.ndarray, np.ndarray]:
    home = LAYOUT.home
    pick = LAYOUT.ik(
        np.array([LAYOUT.base_position[0] - 2.0, LAYOUT.base_position[1], 0.75]),
        LAYOUT.tool_rotation(LAYOUT.box_yaw_at_pick),
        home,
    )
    place = LAYOUT.place_ik(np.array([0.67, 0.62, 0.35]), 0, home)
    assert pick is not None and place is not None
    return pick, place[0]


def _world(wall: bool, **config: object) -> PlanningWorld:
    statics = [WALL] if wall else []
    world = PlanningWorld(LAYOUT.base_position, LAYOUT.base_yaw, statics, PlannerConfig(**config))  # type: ignore[arg-type]
    world.attach(np.array([0.2, 0.15, 0.1]), np.array([0.0, 0.0, -0.1]), np.eye(3))
    return world


def _tcp_length(path: np.ndarray) -> float:
    return path_length(tcp_pose(densify(path, 0.01, 0.01))[0])


def test_open_scene_moves_straight() -> None:
    start, goal = _endpoints()
    world = _world(wall=False)
    try:
        result = MotionPlanner(world).plan(start, goal, seed=1)
    finally:
        world.close()
    assert result.status == "direct" and len(result.path) == 2


def test_a_wall_forces_a_longer_collision_free_path() -> None:
    start, goal = _endpoints()
    open_world, walled = _world(wall=False), _world(wall=True)
    try:
        straight = MotionPlanner(open_world).plan(start, goal, seed=3)
        around = MotionPlanner(walled).plan(start, goal, seed=3)
        assert around.status == "planned", around.status
        assert _tcp_length(around.path) > _tcp_length(straight.path) + 0.05
        walled._limit = 0
        assert not any(walled.in_collision(q) for q in densify(around.path, 0.01, 0.01))
        assert np.allclose(around.path[0], start) and np.allclose(around.path[-1], goal)
    finally:
        open_world.close()
        walled.close()


def test_same_seed_same_path_other_seed_may_differ() -> None:
    start, goal = _endpoints()
    paths = []
    for seed in (5, 5):
        world = _world(wall=True)
        try:
            paths.append(MotionPlanner(world).plan(start, goal, seed=seed).path)
        finally:
            world.close()
    assert paths[0].shape == paths[1].shape and np.array_equal(paths[0], paths[1])


def test_enclosed_goal_fails_within_the_budget() -> None:
    start, goal = _endpoints()
    goal_tcp = LAYOUT.to_world(tcp_pose(goal)[0])
    box = (tuple(goal_tcp - [0, 0, 0.1]), (0.3, 0.3, 0.3))  # the goal pose lies inside a solid block
    world = PlanningWorld(LAYOUT.base_position, LAYOUT.base_yaw, [box], PlannerConfig(max_checks=800))
    try:
        world.attach(np.array([0.2, 0.15, 0.1]), np.array([0.0, 0.0, -0.1]), np.eye(3))
        result = MotionPlanner(world).plan(start, goal, seed=1)
    finally:
        world.close()
    assert result.status == "goal_invalid" and not result.ok


@pytest.mark.parametrize("budget", [50, 300])
def test_budget_is_a_check_count_not_a_clock(budget: int) -> None:
    start, goal = _endpoints()
    world = _world(wall=True, max_checks=budget, simplify_checks=10)
    try:
        result = MotionPlanner(world).plan(start, goal, seed=2)
    finally:
        world.close()
    assert result.status == "failed" and result.checks <= budget + 1


def _lowering(overlap_m: float) -> tuple[PlanningWorld, list[np.ndarray]]:
    """A 30.6 × 15.8 × 27.7 cm box lowered to the deck beside a 21.5 cm tall neighbour it overlaps
    sideways by ``overlap_m`` (DBL's 1 cm grid beside a 17.4 cm box), as the descent's states."""
    neighbour = ((0.6, 0.5, 0.1075), (0.1455, 0.087, 0.1075))  # y 0.413 … 0.587
    world = PlanningWorld(LAYOUT.base_position, LAYOUT.base_yaw, [], PlannerConfig())
    world.set_obstacles([(neighbour[0], (0.0, 0.0, 0.0, 1.0), neighbour[1])])
    half = np.array([0.153, 0.079, 0.1385])
    rotation = LAYOUT.tool_rotation(0.0)
    world.attach(half, rotation.T @ np.array([0.0, 0.0, -half[2]]), rotation.T)
    y = 0.587 - overlap_m + half[1]
    states, q = [], LAYOUT.home
    for bottom in np.arange(0.30, 0.0, -0.005):
        solved = LAYOUT.ik(np.array([0.6, y, bottom + 2 * half[2]]), rotation, q)
        assert solved is not None
        q = solved
        states.append(q)
    return world, states


def test_a_small_sideways_overlap_passes_in_any_order_and_a_large_one_collides() -> None:
    """The check measures the penetration of the current state, whatever was queried before (lowering
    and raising give the same answers); the pack's test on DBL's slot holds the case where Bullet's
    persistent manifolds once reported a 4 mm sideways overlap as 13 mm deep."""
    world, states = _lowering(0.004)
    try:
        assert not any(world.in_collision(q) for q in states)  # 4 mm: within the tolerance all the way
        assert [world.in_collision(q) for q in states[::-1]] == [False] * len(states)
    finally:
        world.close()
    world, states = _lowering(0.02)
    try:
        hits = [world.in_collision(q) for q in states]
        assert not hits[0] and all(hits[-20:])  # 2 cm into the neighbour is still a collision
    finally:
        world.close()
