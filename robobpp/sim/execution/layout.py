"""Where the robot, the pallet and the conveyor stand, and the grasp/place poses that follow.

World frame = the container frame in metres (origin at the inner bottom corner, x along the container
length, z up), so the Physics Pack's world needs no transform. The robot stands on the floor beyond the
container's long side at y = W, its own x axis pointing across the container (−y): bottom-left-first
policies then fill the far side first, as a palletiser is usually taught. The conveyor's pick station
is 90° to the robot's right, clear of the pallet even for 2.5 m panels. The standoff is
chosen so every top-down placement inside all three dataset containers is reachable (tested by
sampling the container volume).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robobpp.core import Box, ContainerSpec
from robobpp.sim.robot import opw
from robobpp.sim.robot.kinematics import rot, top_down_rotation


@dataclass(frozen=True, slots=True)
class Layout:
    container: ContainerSpec
    #: Robot J1 axis to the container's long edge at y = W (m).
    standoff: float = 0.95
    #: Height of the floor the robot and the conveyor stand on (m); the pallet deck top is z = 0.
    floor_z: float = -0.15
    #: The robot stands on a pedestal this high (m), as palletising robots usually do: it lifts the
    #: far top corners of the 1.7 m Diverse stack into reach.
    pedestal: float = 0.3
    #: Pick station (box top-face centre, horizontally) in the robot frame (m).
    pick_xy: tuple[float, float] = (0.0, -2.0)
    #: Conveyor belt top surface height above the pallet deck (m) and its footprint (m, along robot x,
    #: along robot y).
    conveyor_height: float = 0.5
    conveyor_size: tuple[float, float] = (3.2, 0.8)
    #: Lift above the conveyor after the grasp, and the height above the rest pose where the
    #: vertical descent starts (m).
    lift: float = 0.10
    approach: float = 0.05

    @property
    def base_position(self) -> np.ndarray:
        return np.array(
            [
                self.container.length / 200.0,
                self.container.width / 100.0 + self.standoff,
                self.floor_z + self.pedestal,
            ]
        )

    @property
    def base_yaw(self) -> float:
        return -math.pi / 2

    @property
    def base_rotation(self) -> np.ndarray:
        return rot("z", self.base_yaw)

    def to_robot(self, position: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = self.base_rotation
        return r.T @ (np.asarray(position) - self.base_position), r.T @ rotation

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Robot-frame points ``(..., 3)`` in the world frame."""
        world: np.ndarray = np.asarray(points) @ self.base_rotation.T + self.base_position
        return world

    # -- the pick station -------------------------------------------------------------------------
    @property
    def box_yaw_at_pick(self) -> float:
        """World yaw of a box's length axis as it arrives (along the robot's x axis)."""
        return self.base_yaw

    def pick_box_pose(self, box: Box) -> tuple[np.ndarray, float]:
        """World centre (m) and length-axis yaw of a box waiting on the conveyor."""
        top = self.to_world(np.array([self.pick_xy[0], self.pick_xy[1], 0.0]))
        top[2] = self.conveyor_height
        return top + np.array([0.0, 0.0, box.height / 200.0]), self.box_yaw_at_pick

    def conveyor_box(self) -> tuple[np.ndarray, np.ndarray]:
        """World centre and half extents of the conveyor's collision box (aligned with the robot)."""
        centre = self.to_world(np.array([self.pick_xy[0], self.pick_xy[1], 0.0]))
        half_z = (self.conveyor_height - self.floor_z) / 2
        centre[2] = self.floor_z + half_z
        hx, hy = self.conveyor_size[0] / 2, self.conveyor_size[1] / 2
        # The robot frame is the world turned by 90°, so the robot's x extent lies along world y.
        return centre, np.array([hy, hx, half_z])

    # -- tool poses --------------------------------------------------------------------------------
    @staticmethod
    def tool_rotation(box_yaw: float) -> np.ndarray:
        """World tool rotation holding a box whose length axis has world yaw ``box_yaw``.

        The tool's y axis is laid along the box length, so tool yaw = box yaw − 90°.
        """
        return top_down_rotation(box_yaw - math.pi / 2)

    @staticmethod
    def place_yaws(orientation: int) -> tuple[float, float]:
        """World yaws of the box length axis for a placement orientation (a box looks the same turned
        by 180°, so both are offered to the IK)."""
        yaw = 0.0 if orientation == 0 else math.pi / 2
        return yaw, yaw + math.pi

    def ik(self, tcp_world: np.ndarray, rotation_world: np.ndarray, q_near: np.ndarray) -> np.ndarray | None:
        """Joint solution nearest ``q_near`` putting the TCP at a world pose, or None if unreachable."""
        p, r = self.to_robot(tcp_world, rotation_world)
        return opw.nearest(p, r, q_near)

    def place_ik(
        self, tcp_world: np.ndarray, orientation: int, q_near: np.ndarray
    ) -> tuple[np.ndarray, float] | None:
        """Best joint solution (and the box yaw it implies) over the two equivalent box yaws."""
        best: tuple[np.ndarray, float] | None = None
        best_cost = math.inf
        for yaw in self.place_yaws(orientation):
            q = self.ik(tcp_world, self.tool_rotation(yaw), q_near)
            if q is None:
                continue
            cost = float(opw.motion_time(q_near, q))
            if cost < best_cost - 1e-12:
                best, best_cost = (q, yaw), cost
        return best

    @property
    def home(self) -> np.ndarray:
        """Waiting configuration: above the pick station, tool down."""
        top = self.to_world(np.array([self.pick_xy[0], self.pick_xy[1], 0.0]))
        top[2] = self.conveyor_height + 0.6
        q = self.ik(top, self.tool_rotation(self.box_yaw_at_pick), np.array([-1.57, 0.3, 0.0, 0.0, 1.2, 0.0]))
        if q is None:  # pragma: no cover - guarded by the layout test
            raise RuntimeError("layout error: the home pose is unreachable")
        return q
