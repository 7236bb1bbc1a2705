"""Closed-form inverse kinematics for the ortho-parallel-wrist arm (OPW, Brandstötter et al. 2014).

pybullet's damped-least-squares IK ignores joint limits and often fails on this arm; an OPW arm has
at most 8 exact solutions (shoulder front/back × elbow up/down × wrist flip), found here in closed
form and then widened by the ±2π turns joints 4 and 6 allow. The solver works directly in the robot's
joint angles: the published OPW offset of joint 3 (−90°) is what makes the forearm horizontal at
q3 = 0, which the geometry below already encodes (forearm vector ``(c3, 0, −a2)`` in the joint-3
frame). The lateral offset ``b`` is 0 for this arm; other values are refused rather than mis-solved.
"""

from __future__ import annotations

import math

import numpy as np

from robobpp.sim.robot.facts import LOWER, MAX_SPEED, OPW, TOOL, UPPER, OPWParameters
from robobpp.sim.robot.kinematics import rot

_SINGULAR = 1e-9


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def _turn_variants(q: np.ndarray) -> list[np.ndarray]:
    """The same pose reached with joints 4 and/or 6 turned by whole revolutions, within limits."""
    out = []
    for d4 in (-2 * math.pi, 0.0, 2 * math.pi):
        for d6 in (-4 * math.pi, -2 * math.pi, 0.0, 2 * math.pi, 4 * math.pi):
            v = q.copy()
            v[3] += d4
            v[5] += d6
            if np.all(v >= LOWER - 1e-9) and np.all(v <= UPPER + 1e-9):
                out.append(np.clip(v, LOWER, UPPER))
    return out


def solve(
    position: np.ndarray,
    rotation: np.ndarray,
    q_hint: np.ndarray | None = None,
    params: OPWParameters = OPW,
    tool_length: float = TOOL.length,
) -> np.ndarray:
    """Every joint solution ``(k, 6)`` within limits placing the TCP at ``position`` with ``rotation``.

    ``rotation``'s x column is the tool axis. ``q_hint`` only chooses joint 4 at a wrist singularity
    (q5 = 0, where only q4 + q6 is determined). Empty array when the pose is out of reach.
    """
    if params.b != 0.0:
        raise ValueError("this OPW solver handles b = 0 arms only")
    p = np.asarray(position, dtype=float)
    r = np.asarray(rotation, dtype=float)
    tool_axis = r[:, 0]
    centre = p - (params.c4 + tool_length) * tool_axis
    forearm = math.hypot(params.c3, params.a2)
    psi = math.atan2(-params.a2, params.c3)
    radial = math.hypot(centre[0], centre[1])
    base_angle = math.atan2(centre[1], centre[0])
    solutions: list[np.ndarray] = []
    for q1, reach in ((base_angle, radial), (base_angle + math.pi, -radial)):
        dr, dz = reach - params.a1, centre[2] - params.c1
        k = (dr * dr + dz * dz - params.c2**2 - forearm**2) / (2 * params.c2 * forearm)
        if abs(k) > 1.0 + 1e-12:
            continue
        spread = math.acos(max(-1.0, min(1.0, k)))
        for delta in {spread, -spread}:
            alpha1 = math.atan2(dz, dr) - math.atan2(
                forearm * math.sin(delta), params.c2 + forearm * math.cos(delta)
            )
            q2 = math.pi / 2 - alpha1
            q3 = psi - (alpha1 + delta) - q2
            r03 = rot("z", q1) @ rot("y", q2 + q3)
            m = r03.T @ r
            c5 = max(-1.0, min(1.0, m[0, 0]))
            for q5 in {math.acos(c5), -math.acos(c5)}:
                s5 = math.sin(q5)
                if abs(s5) < _SINGULAR:
                    q4 = float(q_hint[3]) if q_hint is not None else 0.0
                    q6 = math.atan2(m[2, 1], m[1, 1]) * (1 if c5 > 0 else -1) - q4
                else:
                    q4 = math.atan2(m[1, 0] / s5, -m[2, 0] / s5)
                    q6 = math.atan2(m[0, 1] / s5, m[0, 2] / s5)
                q = np.array([_wrap(q1), _wrap(q2), _wrap(q3), _wrap(q4), q5, _wrap(q6)])
                solutions.extend(_turn_variants(q))
    if not solutions:
        return np.zeros((0, 6))
    return np.unique(np.round(np.array(solutions), 12), axis=0)


def motion_time(q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    """Synchronous joint move time (s) under the joint speed limits; broadcasts over rows."""
    seconds: np.ndarray = np.max(np.abs(np.asarray(q_to) - np.asarray(q_from)) / MAX_SPEED, axis=-1)
    return seconds


def nearest(
    position: np.ndarray,
    rotation: np.ndarray,
    q_current: np.ndarray,
    params: OPWParameters = OPW,
    tool_length: float = TOOL.length,
) -> np.ndarray | None:
    """The solution the arm reaches soonest from ``q_current`` (joint speed limits), or None."""
    candidates = solve(position, rotation, q_current, params, tool_length)
    if len(candidates) == 0:
        return None
    cost = motion_time(q_current, candidates) + 1e-6 * np.linalg.norm(candidates - q_current, axis=1)
    best: np.ndarray = candidates[int(np.argmin(cost))]
    return best
