"""The ABB IRB 6700-200/2.60 with a suction tool: facts, URDF, forward and OPW inverse kinematics."""

from robobpp.sim.robot.facts import JOINTS, LOWER, MAX_SPEED, OPW, TOOL, UPPER
from robobpp.sim.robot.kinematics import joint_frames, path_length, tcp_pose, top_down_rotation
from robobpp.sim.robot.opw import motion_time, nearest, solve
from robobpp.sim.robot.urdf import LINK_NAMES, TCP_LINK, TOOL_LINK, urdf_path, urdf_text

__all__ = [
    "JOINTS",
    "LINK_NAMES",
    "LOWER",
    "MAX_SPEED",
    "OPW",
    "TCP_LINK",
    "TOOL",
    "TOOL_LINK",
    "UPPER",
    "joint_frames",
    "motion_time",
    "nearest",
    "path_length",
    "solve",
    "tcp_pose",
    "top_down_rotation",
    "urdf_path",
    "urdf_text",
]
