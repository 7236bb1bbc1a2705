"""Forward kinematics of the arm in numpy, written from the same joint table as the URDF.

Batched (``q`` may be ``(6,)`` or ``(n, 6)``) because trajectory length and the reachability test
evaluate thousands of configurations; calling pybullet for each would be far slower.
"""

from __future__ import annotations

import numpy as np

from robobpp.sim.robot.facts import JOINTS, TOOL

_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


def rot(axis: str, angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about a principal axis; shape ``(..., 3, 3)``."""
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    i = _AXIS_INDEX[axis]
    j, k = (i + 1) % 3, (i + 2) % 3
    out[..., i, i] = 1.0
    out[..., j, j] = c
    out[..., k, k] = c
    out[..., j, k] = -s
    out[..., k, j] = s
    return out


def joint_frames(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(..., 7, 3)`` and rotations ``(..., 7, 3, 3)`` of the six joint frames and the TCP.

    Frame i (0..5) is the child link frame of joint i+1; frame 6 is the tool centre point. Robot base
    frame = world frame (callers add the base pose).
    """
    q = np.asarray(q, dtype=float)
    batch = q.shape[:-1]
    pos = np.zeros(batch + (3,))
    r = np.broadcast_to(np.eye(3), batch + (3, 3)).copy()
    positions, rotations = [], []
    for i, joint in enumerate(JOINTS):
        pos = pos + np.einsum("...ij,j->...i", r, np.asarray(joint.origin))
        r = r @ rot(joint.axis, q[..., i])
        positions.append(pos)
        rotations.append(r)
    tcp = pos + r[..., :, 0] * TOOL.length
    positions.append(tcp)
    rotations.append(r)
    return np.stack(positions, axis=-2), np.stack(rotations, axis=-3)


def tcp_pose(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCP position ``(..., 3)`` and rotation ``(..., 3, 3)`` (tool axis = rotation's x column)."""
    positions, rotations = joint_frames(q)
    return positions[..., 6, :], rotations[..., 6, :, :]


def flange_position(q: np.ndarray) -> np.ndarray:
    return joint_frames(q)[0][..., 5, :]


def path_length(points: np.ndarray) -> float:
    """Length of a polyline ``(n, 3)``."""
    if len(points) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def top_down_rotation(yaw: float) -> np.ndarray:
    """Tool rotation for a top-down suction grasp: tool axis (x) pointing down, yawed about world z.

    The tool's y axis is the box's length direction at yaw 0.
    """
    rotation: np.ndarray = rot("z", yaw) @ rot("y", np.pi / 2)
    return rotation
