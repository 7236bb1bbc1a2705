"""The robot model: URDF and numpy FK agree, OPW IK is exact, limited, and picks the nearest solution."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest

from robobpp.sim.robot import LOWER, OPW, UPPER, nearest, solve, tcp_pose, urdf_path
from robobpp.sim.robot.facts import OPWParameters
from robobpp.sim.robot.kinematics import flange_position, top_down_rotation
from robobpp.sim.robot.urdf import TCP_LINK


def test_flange_at_zero_matches_the_datasheet() -> None:
    assert np.allclose(flange_position(np.zeros(6)), [1.6625, 0.0, 2.105])


def test_urdf_and_numpy_forward_kinematics_agree() -> None:
    cid = p.connect(p.DIRECT)
    try:
        robot = p.loadURDF(urdf_path(), useFixedBase=True, physicsClientId=cid)
        assert p.getNumJoints(robot, physicsClientId=cid) == 8
        rng = np.random.default_rng(1)
        for _ in range(20):
            q = rng.uniform(LOWER, UPPER)
            for j in range(6):
                p.resetJointState(robot, j, q[j], physicsClientId=cid)
            state = p.getLinkState(robot, TCP_LINK, computeForwardKinematics=True, physicsClientId=cid)
            position, rotation = tcp_pose(q)
            assert np.allclose(state[4], position, atol=1e-6)
            assert np.allclose(np.reshape(p.getMatrixFromQuaternion(state[5]), (3, 3)), rotation, atol=1e-6)
    finally:
        p.disconnect(cid)


def test_ik_recovers_random_configurations_exactly() -> None:
    rng = np.random.default_rng(0)
    for _ in range(300):
        q = rng.uniform(LOWER, UPPER)
        position, rotation = tcp_pose(q)
        solutions = solve(position, rotation, q)
        assert len(solutions) >= 1
        assert np.all(solutions >= LOWER - 1e-9) and np.all(solutions <= UPPER + 1e-9)
        got_p, got_r = tcp_pose(solutions)
        assert np.abs(got_p - position).max() < 1e-7
        assert np.abs(got_r - rotation).max() < 1e-7
        assert np.abs(solutions - q).max(axis=1).min() < 1e-6  # the original is among them
        best = nearest(position, rotation, q)
        assert best is not None and np.abs(best - q).max() < 1e-6


def test_ik_gives_several_branches_for_an_ordinary_pose() -> None:
    solutions = solve(np.array([1.5, 0.3, 0.8]), top_down_rotation(0.2))
    # shoulder/elbow/wrist branches, plus the turns of joints 4 and 6
    distinct_arm = {tuple(np.round(s[:3], 6)) for s in solutions}
    assert len(distinct_arm) >= 2 and len(solutions) >= 4


def test_out_of_reach_has_no_solution() -> None:
    assert len(solve(np.array([3.5, 0.0, 1.0]), top_down_rotation(0.0))) == 0
    assert nearest(np.array([0.0, 0.0, 6.0]), top_down_rotation(0.0), np.zeros(6)) is None


def test_lateral_offset_is_refused() -> None:
    with pytest.raises(ValueError, match="b = 0"):
        solve(np.array([1.5, 0.0, 1.0]), top_down_rotation(0.0), params=OPWParameters(b=0.1))
    assert OPW.b == 0.0
