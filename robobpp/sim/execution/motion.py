"""Pick-to-place joint trajectories: Cartesian lift and descent, time parameterisation, TCP length.

Timing model (documented in docs/execution.md): each waypoint-to-waypoint segment is a synchronous
joint move whose duration is the slowest joint's |Δq| / max speed (no acceleration phase), and on the
Cartesian segments (lift, descent) also at least |ΔTCP| / ``cartesian_speed``. The sum is the
operation's execution time that Dangerous Operation compares with the safe threshold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robobpp.sim.execution.layout import Layout
from robobpp.sim.robot.facts import MAX_SPEED
from robobpp.sim.robot.kinematics import path_length, tcp_pose


@dataclass(slots=True)
class Trajectory:
    """Joint waypoints with the duration of the segment leading to each (``durations[0] = 0``)."""

    waypoints: np.ndarray  # (n, 6)
    durations: np.ndarray  # (n,)
    #: Index one past the last waypoint of each segment :func:`build` joined (lift, transfer, descent).
    segment_ends: tuple[int, ...] = ()

    @property
    def duration(self) -> float:
        return float(self.durations.sum())

    def tcp_length(self) -> float:
        """TCP path length (m) of the trajectory, densified to 1 cm / 0.01 rad."""
        from robobpp.sim.planner import densify

        return path_length(tcp_pose(densify(self.waypoints, 0.01, 0.01))[0])

    def sample_counts(self, dt: float) -> np.ndarray:
        """How many ``dt`` ticks each segment takes when driven (``[0, n1, n2, ...]``, at least one)."""
        counts = np.maximum(1, np.ceil(self.durations / dt - 1e-9)).astype(int)
        counts[0] = 0
        return counts

    def samples(self, dt: float) -> np.ndarray:
        """Configurations at every ``dt`` of execution, ending exactly on the last waypoint."""
        out = [self.waypoints[:1]]
        for i, n in enumerate(self.sample_counts(dt)[1:], start=1):
            t = np.arange(1, n + 1)[:, None] / n
            out.append(self.waypoints[i - 1] + t * (self.waypoints[i] - self.waypoints[i - 1]))
        return np.concatenate(out)


def joint_time(qa: np.ndarray, qb: np.ndarray) -> float:
    return float(np.max(np.abs(np.asarray(qb) - np.asarray(qa)) / MAX_SPEED))


def cartesian_line(
    layout: Layout, q_start: np.ndarray, tcp_end: np.ndarray, step_m: float = 0.02
) -> np.ndarray | None:
    """Joint waypoints moving the TCP in a straight line (same tool attitude) from ``q_start``'s pose
    to ``tcp_end`` (world), each the IK solution nearest the previous; None if any point is unreachable
    or the arm would have to flip."""
    p_robot, r_robot = tcp_pose(q_start)
    start_world = layout.to_world(p_robot)
    rotation_world = layout.base_rotation @ r_robot
    distance = float(np.linalg.norm(np.asarray(tcp_end) - start_world))
    n = max(1, math.ceil(distance / step_m))
    out = [np.asarray(q_start, dtype=float)]
    for k in range(1, n + 1):
        point = start_world + (np.asarray(tcp_end) - start_world) * (k / n)
        q = layout.ik(point, rotation_world, out[-1])
        if q is None or joint_time(out[-1], q) > 0.5:  # a wrist flip is not a straight line
            return None
        out.append(q)
    return np.stack(out)


def build(segments: list[tuple[np.ndarray, bool]], cartesian_speed: float) -> Trajectory:
    """Join ``(waypoints, is_cartesian)`` segments (each starting where the last ended) and time them."""
    points: list[np.ndarray] = []
    durations: list[float] = []
    ends: list[int] = []
    for waypoints, cartesian in segments:
        start = 0 if not points else 1
        if points:
            assert np.allclose(points[-1], waypoints[0], atol=1e-6), "segments must join"
        else:
            points.append(waypoints[0])
            durations.append(0.0)
        tcp = tcp_pose(waypoints)[0] if cartesian else None
        for i in range(max(start, 1), len(waypoints)):
            t = joint_time(waypoints[i - 1], waypoints[i])
            if tcp is not None:
                t = max(t, float(np.linalg.norm(tcp[i] - tcp[i - 1])) / cartesian_speed)
            points.append(waypoints[i])
            durations.append(t)
        ends.append(len(points))
    return Trajectory(np.stack(points), np.array(durations), tuple(ends))


def tool_path_cm(trajectory: Trajectory, layout: Layout, max_points: int = 60) -> list[list[float]]:
    """The TCP path in the container frame (cm, rounded to 0.1 mm) for the replay trace: the densified
    path resampled at equal arc length to at most ``max_points`` points, both ends kept exactly."""
    from robobpp.sim.planner import densify

    points = layout.to_world(tcp_pose(densify(trajectory.waypoints, 0.01, 0.01))[0]) * 100.0
    if len(points) > max_points:
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        wanted = np.linspace(0.0, arc[-1], max_points)
        picks = np.unique(np.clip(np.searchsorted(arc, wanted), 0, len(points) - 1))
        picks[0], picks[-1] = 0, len(points) - 1
        points = points[np.unique(picks)]
    return [[round(float(v), 2) for v in point] for point in points]
