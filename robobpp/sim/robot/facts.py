"""The ABB IRB 6700-200/2.60 as published facts (docs/benchmark.md, "Settings"), plus our suction tool.

Everything robot-specific lives here so the URDF, the forward kinematics and the OPW solver are all
written from the same numbers and cannot drift apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class JointFact:
    name: str
    #: Unit rotation axis in the parent link frame ("x", "y" or "z").
    axis: str
    #: Origin of the joint in the parent link frame, metres.
    origin: tuple[float, float, float]
    lower: float  # rad
    upper: float  # rad
    max_speed: float  # rad/s


def _deg(value: float) -> float:
    return math.radians(value)


#: The six revolute joints, base to flange (ROS-Industrial abb_irb6700 support package values).
JOINTS: tuple[JointFact, ...] = (
    JointFact("joint_1", "z", (0.0, 0.0, 0.780), _deg(-170), _deg(170), _deg(110)),
    JointFact("joint_2", "y", (0.320, 0.0, 0.0), _deg(-65), _deg(85), _deg(110)),
    JointFact("joint_3", "y", (0.0, 0.0, 1.125), _deg(-180), _deg(70), _deg(110)),
    JointFact("joint_4", "x", (0.0, 0.0, 0.200), _deg(-300), _deg(300), _deg(190)),
    JointFact("joint_5", "y", (1.1425, 0.0, 0.0), _deg(-130), _deg(130), _deg(150)),
    JointFact("joint_6", "x", (0.200, 0.0, 0.0), _deg(-360), _deg(360), _deg(210)),
)

LOWER = np.array([j.lower for j in JOINTS])
UPPER = np.array([j.upper for j in JOINTS])
MAX_SPEED = np.array([j.max_speed for j in JOINTS])


@dataclass(frozen=True, slots=True)
class OPWParameters:
    """Ortho-parallel-wrist parameters (Brandstötter et al. 2014) of the arm.

    ``offsets`` map OPW joint angles to the robot's: q_robot = q_opw - offset... here they are the
    published values; the solver in :mod:`robobpp.sim.robot.opw` documents how it applies them.
    """

    a1: float = 0.32
    a2: float = -0.2
    b: float = 0.0
    c1: float = 0.78
    c2: float = 1.125
    c3: float = 1.1425
    c4: float = 0.2
    offsets: tuple[float, ...] = (0.0, 0.0, -math.pi / 2, 0.0, 0.0, 0.0)


OPW = OPWParameters()


@dataclass(frozen=True, slots=True)
class ToolFact:
    """Suction gripper on the flange, along the flange x axis (the J6 axis).

    The tool centre point (TCP) is the face of the suction cup: ``length`` beyond the flange.
    """

    length: float = 0.40
    radius: float = 0.045
    mass: float = 15.0
    #: Suction capacity, kg per m² of grasped top area (paper, after Zhao et al. 2025).
    capacity_kg_m2: float = 260.0


TOOL = ToolFact()

#: Rough link masses (kg) for a 1.2 t class robot: base, links 1..6, tool. Only used by the physics
#: world's contact response; the arm is driven kinematically, so they need only be plausible.
LINK_MASSES: tuple[float, ...] = (400.0, 300.0, 160.0, 120.0, 60.0, 20.0, 5.0)
