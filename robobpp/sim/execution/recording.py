"""What the Execution Pack writes into the trace so the replay can draw the robot doing each operation.

Two records, both plain JSON:

- ``extra["cell"]`` (first operation of an episode): the robot cell — the joint table and link shapes
  of :mod:`robobpp.sim.robot` (the very numbers the URDF, the forward kinematics and the IK are written
  from), the tool, the base pose, the pedestal, the conveyor and its pick point. The replay computes the
  arm's forward kinematics from it, so the page never holds a second copy of the robot.
- ``extra["motion"]`` (every operation): the arm's joint angles over the operation's time line::

      {"tick_s": dt,                                  # times count ticks of the physical world (1/240 s)
       "t": [tick, ...], "q": [j1, ..., j6, j1, ...], # waypoints: time from the step's start, angles × 10⁴
       "phases": [["pick", t0, t1], ["transfer", t1, t2], ["retreat", t2, t3]],
       "grip": [t_on, t_off],                          # suction on (ticks)
       "carry": [x, y, z, qx, qy, qz, qw]}             # the carried box in the TCP frame (m, quaternion)

  The arm moves joint-linearly between waypoints, as the simulator drives it. *transfer* is the
  simulated trajectory (lift, planned move, descent) at the times the physical world stepped it, so the
  step's box track (``extra["track"]``, :mod:`robobpp.sim.physics.recording`) lines up with it. *pick*
  (from the waiting pose down to the grasp) and *retreat* (back out along the transfer, then up to the
  waiting pose) are not simulated — the simulator starts each operation at the grasp and puts the arm back
  at once (docs/execution.md) — and are recorded so the replay shows a whole cycle. Waypoints a straight
  joint-space line through their neighbours reproduces within ``tolerance_rad`` are dropped.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from robobpp.sim.execution import motion
from robobpp.sim.execution.layout import Layout
from robobpp.sim.planner import quaternion
from robobpp.sim.robot.facts import JOINTS, TOOL
from robobpp.sim.robot.kinematics import tcp_pose
from robobpp.sim.robot.urdf import LINK_NAMES, SHAPES

#: Joint angles are stored as integers in units of 10⁻⁴ rad (0.26 mm at the arm's 2.6 m reach).
Q_SCALE = 10_000
#: Largest joint error (rad) of the simplified waypoint list against the full one.
TOLERANCE_RAD = 5e-4
#: IK step (m) of the replay-only straight moves (pick, the final rise): they are only drawn, and the
#: joint-linear chord between two poses 10 cm apart strays from the straight line by well under a cm.
REPLAY_LINE_STEP_M = 0.10


def cell(layout: Layout) -> dict[str, Any]:
    """The robot cell for the replay (metres, radians; world = container frame in metres)."""
    frames = ("base_link", *LINK_NAMES[:7])  # base, link_1..link_6, tool (tcp has no shape)

    def r(v: float) -> float:  # a rounding shorthand for the JSON below
        return round(float(v), 6)

    centre, half = layout.conveyor_box()
    pick = layout.to_world(np.array([layout.pick_xy[0], layout.pick_xy[1], 0.0]))
    return {
        "base": [*(r(v) for v in layout.base_position), r(layout.base_yaw)],
        "floor_z": r(layout.floor_z),
        "joints": [[j.axis, *(r(v) for v in j.origin), r(j.lower), r(j.upper)] for j in JOINTS],
        "tool": [r(TOOL.length), r(TOOL.radius)],
        "shapes": [
            [
                [s.kind, [r(v) for v in s.size], [r(v) for v in s.xyz], [r(v) for v in s.rpy]]
                for s in SHAPES[f]
            ]
            for f in frames
        ],
        "conveyor": [*(r(v) for v in centre), *(r(v) for v in half)],  # world-aligned box
        "pick": [r(pick[0]), r(pick[1]), r(layout.conveyor_height)],
        "home": [r(v) for v in layout.home],
    }


def motion_record(
    trajectory: motion.Trajectory,
    layout: Layout,
    dt: float,
    cartesian_speed: float,
    carry: tuple[np.ndarray, np.ndarray],
    tolerance_rad: float = TOLERANCE_RAD,
) -> dict[str, Any]:
    """The operation's joint time line (see the module docstring); ``carry`` = the carried box's centre
    (m) and rotation matrix in the TCP frame."""
    home = layout.home
    q_grasp = trajectory.waypoints[0]
    # Times in ticks of the world (``dt``): the transfer exactly as driven, pick and retreat to the tick.
    # Pick: straight down from the waiting pose (above the pick station) onto the box's top face.
    pick = _line_or_joint(layout, home, layout.to_world(tcp_pose(q_grasp)[0]), q_grasp)
    pick_t = _ticks(motion.build([(pick, True)], cartesian_speed), dt)
    # Transfer: at the ticks of the world that drove it.
    transfer_t = pick_t[-1] + np.cumsum(trajectory.sample_counts(dt))
    release = int(transfer_t[-1])
    # Retreat: back out along the transfer to the top of the lift, then up to the waiting pose.
    lift_end = trajectory.segment_ends[0] - 1 if trajectory.segment_ends else 0
    back = trajectory.waypoints[lift_end:][::-1]
    back_t = release + (release - transfer_t[lift_end:][::-1])
    up = _line_or_joint(layout, back[-1], layout.to_world(tcp_pose(home)[0]), home)
    up_t = back_t[-1] + _ticks(motion.build([(up, True)], cartesian_speed), dt)
    q = np.concatenate([pick, trajectory.waypoints[1:], back[1:], up[1:]])
    t = np.concatenate([pick_t, transfer_t[1:], back_t[1:], up_t[1:]])
    keep = _simplify(t.astype(float), q, tolerance_rad)
    offset, rotation = carry
    grasp, end = int(pick_t[-1]), int(up_t[-1])
    return {
        "tick_s": dt,
        "t": t[keep].astype(int).tolist(),
        "q": np.round(q[keep] * Q_SCALE).astype(np.int64).reshape(-1).tolist(),
        "phases": [["pick", 0, grasp], ["transfer", grasp, release], ["retreat", release, end]],
        "grip": [grasp, release],
        "carry": [round(float(v), 5) for v in offset] + [round(float(v), 6) for v in quaternion(rotation)],
    }


def _ticks(trajectory: motion.Trajectory, dt: float) -> np.ndarray:
    """Waypoint times of a replay-only move, in whole ticks (at least one per segment)."""
    return np.cumsum(trajectory.sample_counts(dt))


def _line_or_joint(layout: Layout, q_from: np.ndarray, tcp_to: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    """A straight TCP line from ``q_from`` to ``tcp_to`` ending exactly on ``q_to``; the plain joint move
    when the line is not reachable."""
    line = motion.cartesian_line(layout, q_from, tcp_to, REPLAY_LINE_STEP_M)
    if line is None or motion.joint_time(line[-1], q_to) > 1e-3:
        return np.stack([np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)])
    line[-1] = q_to
    return line


def _simplify(t: np.ndarray, q: np.ndarray, tolerance: float) -> np.ndarray:
    """Indices of the waypoints to keep (Douglas–Peucker over time, max joint error ≤ ``tolerance``)."""
    keep = np.zeros(len(t), dtype=bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(t) - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        span = t[b] - t[a]
        w = (t[a + 1 : b] - t[a]) / span if span > 0 else np.zeros(b - a - 1)
        between = q[a] + w[:, None] * (q[b] - q[a])
        error = np.abs(q[a + 1 : b] - between).max(axis=1)
        worst = int(np.argmax(error))
        if error[worst] > tolerance:
            k = a + 1 + worst
            keep[k] = True
            stack += [(a, k), (k, b)]
    return np.flatnonzero(keep)
