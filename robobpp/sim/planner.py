"""Collision-free joint-space transfer planning with OMPL 2.x (RRTConnect) in a private pybullet world.

The planning world is a separate DIRECT client holding the robot, the static scene and *static copies*
of the placed boxes at their actual poses; the carried box rides on the tool. Nothing here steps a
simulation, so planning never disturbs the physical world.

Reproducibility: OMPL's RNG is seeded before every query (``ompl.util.RNG.setSeed``), and the budget
is a number of state-validity checks, never wall time, so the same scene and seed give the same path on
any machine. The straight joint-space move is tried first (an industrial robot's default PTP motion);
only when it collides does RRTConnect search, and its path is shortcut-simplified under the same kind of
budget. Every returned path is re-checked densely (joint step ≤ ``check_step_rad`` and TCP step ≤
``check_step_m``), coarser OMPL motion checks notwithstanding.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from time import perf_counter

import numpy as np
import ompl.base as ob
import ompl.geometric as og
import ompl.util as ou
import pybullet as p

from robobpp.sim.robot.facts import LOWER, UPPER
from robobpp.sim.robot.kinematics import tcp_pose
from robobpp.sim.robot.urdf import LINK_NAMES, TOOL_LINK, urdf_path

#: A joint configuration, position or size: callers pass tuples, lists and numpy arrays alike.
Vector = Sequence[float] | np.ndarray

ou.setLogLevel(ou.LOG_WARN)

#: Robot links whose contact with the carried box is the grasp itself, not a collision.
_GRIP_LINKS = frozenset({TOOL_LINK, LINK_NAMES.index("link_6"), LINK_NAMES.index("tcp")})


@dataclass(frozen=True, slots=True)
class PlannerConfig:
    #: State-validity checks one query may spend (search + simplification); the planning budget.
    max_checks: int = 6000
    #: Of which the shortcut simplification may use at most this many.
    simplify_checks: int = 1500
    #: RRTConnect's step (rad, joint-space Euclidean).
    rrt_range: float = 0.6
    #: OMPL motion-check resolution (rad) during the search.
    search_step_rad: float = 0.04
    #: Dense re-check of the final path.
    check_step_rad: float = 0.01
    check_step_m: float = 0.01
    #: Penetration (m) tolerated between the carried box and placed boxes: neighbours packed flush
    #: touch the descent column, and settling leaves boxes a few millimetres off their cells. The
    #: Execution Pack's carried box is already 5 mm smaller per side (``carried_margin_cm``), so a
    #: full-size overlap of up to 1 cm passes.
    box_tolerance_m: float = 0.005
    #: Clearance (m) the arm keeps from everything.
    arm_clearance_m: float = 0.0


@dataclass(slots=True)
class PlanResult:
    path: np.ndarray  # (n, 6) waypoints, start first, goal last
    status: str  # "direct" | "via" | "planned" | "failed" | "start_invalid" | "goal_invalid"
    checks: int
    seconds: float  # wall time, reported only (never decides anything)

    @property
    def ok(self) -> bool:
        return self.status in ("direct", "via", "planned")


class _Budget(Exception):
    pass


class PlanningWorld:
    """Robot + static scene + static copies of the placed boxes + the attached carried box."""

    def __init__(
        self,
        base_position: Vector,
        base_yaw: float,
        statics: Sequence[tuple[Vector, Vector]] = (),
        config: PlannerConfig | None = None,
    ) -> None:
        """``statics``: (centre, half extents) of axis-aligned static scene boxes, metres."""
        self.config = config or PlannerConfig()
        self.client = p.connect(p.DIRECT)
        cid = self.client
        p.setPhysicsEngineParameter(deterministicOverlappingPairs=1, physicsClientId=cid)
        base_quat = p.getQuaternionFromEuler((0, 0, base_yaw))
        self.robot = p.loadURDF(urdf_path(), base_position, base_quat, useFixedBase=True, physicsClientId=cid)
        self.scene: list[int] = []
        for centre, half in statics:
            shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(half), physicsClientId=cid)
            self.scene.append(p.createMultiBody(0, shape, -1, list(centre), physicsClientId=cid))
        self._obstacles: list[int] = []
        self._obstacle_shapes: dict[tuple[float, ...], int] = {}
        self.carried: int | None = None
        self._carried_offset = np.zeros(3)
        self._carried_rot = np.eye(3)
        self.checks = 0
        self._limit = 0

    def close(self) -> None:
        if self.client >= 0:
            with contextlib.suppress(p.error):
                p.disconnect(physicsClientId=self.client)
            self.client = -1

    def __del__(self) -> None:
        with contextlib.suppress(Exception):  # interpreter shutdown
            self.close()

    # -- scene -------------------------------------------------------------------------------------
    def _shape(self, half: Vector) -> int:
        key = tuple(round(float(h), 6) for h in half)
        shape = self._obstacle_shapes.get(key)
        if shape is None:
            shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(key), physicsClientId=self.client)
            self._obstacle_shapes[key] = shape
        return shape

    def set_obstacles(self, boxes: Sequence[tuple[Vector, Vector, Vector]]) -> None:
        """Static copies of the placed boxes: (centre m, quaternion xyzw, half extents m) each, in order.

        Bodies are reused by position in the list; a changed size replaces the body.
        """
        cid = self.client
        for i, (centre, quat, half) in enumerate(boxes):
            if i < len(self._obstacles):
                body = self._obstacles[i]
                data = p.getCollisionShapeData(body, -1, physicsClientId=cid)[0]
                if np.allclose(np.asarray(data[3]) / 2, half, atol=1e-6):
                    p.resetBasePositionAndOrientation(body, list(centre), list(quat), physicsClientId=cid)
                    continue
                p.removeBody(body, physicsClientId=cid)
                self._obstacles[i] = p.createMultiBody(
                    0, self._shape(half), -1, list(centre), list(quat), physicsClientId=cid
                )
            else:
                self._obstacles.append(
                    p.createMultiBody(0, self._shape(half), -1, list(centre), list(quat), physicsClientId=cid)
                )
        while len(self._obstacles) > len(boxes):
            p.removeBody(self._obstacles.pop(), physicsClientId=cid)

    def attach(self, half_extents: Vector, offset: np.ndarray, rotation: np.ndarray) -> None:
        """Carry a box: its centre at ``offset`` and its axes ``rotation`` in the TCP frame."""
        self.detach()
        shape = p.createCollisionShape(
            p.GEOM_BOX, halfExtents=list(half_extents), physicsClientId=self.client
        )
        # Mass > 0 so Bullet pairs it with the static scene; the world is never stepped.
        self.carried = p.createMultiBody(1.0, shape, -1, [0, 0, -10], physicsClientId=self.client)
        self._carried_offset = np.asarray(offset, dtype=float)
        self._carried_rot = np.asarray(rotation, dtype=float)

    def detach(self) -> None:
        if self.carried is not None:
            p.removeBody(self.carried, physicsClientId=self.client)
            self.carried = None

    # -- checking ----------------------------------------------------------------------------------
    def set_config(self, q: Vector, tcp: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Put the arm (and the carried box) at ``q``; ``tcp`` is the world TCP pose if already known."""
        cid = self.client
        for j in range(6):
            p.resetJointState(self.robot, j, float(q[j]), physicsClientId=cid)
        if self.carried is not None:
            if tcp is None:
                state = p.getLinkState(
                    self.robot, LINK_NAMES.index("tcp"), computeForwardKinematics=True, physicsClientId=cid
                )
                position = np.asarray(state[4])
                rotation = np.asarray(p.getMatrixFromQuaternion(state[5])).reshape(3, 3)
            else:
                position, rotation = tcp
            centre = position + rotation @ self._carried_offset
            quat = _quaternion(rotation @ self._carried_rot)
            p.resetBasePositionAndOrientation(self.carried, centre.tolist(), quat, physicsClientId=cid)

    def in_collision(self, q: Vector) -> bool:
        """Arm or carried box touching anything (beyond the tolerances) at ``q``. Counts against the budget.

        ``getContactPoints`` after ``performCollisionDetection`` reads Bullet's *persistent* contact
        manifolds: a point found at an earlier query stays while the bodies only slide along its normal's
        plane, and its depth is re-projected along that old normal. A carried box lowered beside a
        neighbour it overlaps by 4 mm sideways was thus reported 13 mm deep along z (the point from when
        its bottom first touched the neighbour's top edge), and the planner refused valid descents into
        DBL's tight slots. The manifolds still name every pair that may penetrate (the fresh, deepest
        point is always kept), so each pair reported beyond the tolerance is measured afresh with
        ``getClosestPoints`` before it counts.
        """
        self.checks += 1
        if self._limit and self.checks > self._limit:
            raise _Budget
        self.set_config(q)
        cid = self.client
        p.performCollisionDetection(physicsClientId=cid)
        suspects: set[tuple[int, int, int, int, float]] = set()
        for contact in p.getContactPoints(bodyA=self.robot, physicsClientId=cid):
            if contact[3] < 0:  # the base never moves; its floor contact is no collision
                continue
            if contact[2] == self.carried and contact[3] in _GRIP_LINKS:
                continue
            if contact[8] < -self.config.arm_clearance_m:
                suspects.add((self.robot, contact[3], contact[2], contact[4], self.config.arm_clearance_m))
        if self.carried is not None:
            for contact in p.getContactPoints(bodyA=self.carried, physicsClientId=cid):
                if contact[2] == self.robot:
                    continue
                if contact[8] < -self.config.box_tolerance_m:
                    suspects.add((self.carried, -1, contact[2], contact[4], self.config.box_tolerance_m))
        for body_a, link_a, body_b, link_b, tolerance in sorted(suspects):
            fresh = p.getClosestPoints(
                body_a, body_b, 0.0, linkIndexA=link_a, linkIndexB=link_b, physicsClientId=cid
            )
            if any(point[8] < -tolerance for point in fresh or ()):
                return True
        return False

    def segment_free(self, qa: np.ndarray, qb: np.ndarray) -> bool:
        """Dense check of the straight joint move ``qa → qb`` (end point included, start excluded)."""
        for q in densify(np.stack([qa, qb]), self.config.check_step_rad, self.config.check_step_m)[1:]:
            if self.in_collision(q):
                return False
        return True


def _quaternion(r: np.ndarray) -> list[float]:
    """Rotation matrix → (x, y, z, w)."""
    t = r[0, 0] + r[1, 1] + r[2, 2]
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        return [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s]
    i = int(np.argmax([r[0, 0], r[1, 1], r[2, 2]]))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = math.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k]) * 2
    out = [0.0, 0.0, 0.0, 0.0]
    out[i] = 0.25 * s
    out[j] = (r[j, i] + r[i, j]) / s
    out[k] = (r[k, i] + r[i, k]) / s
    out[3] = (r[k, j] - r[j, k]) / s
    return out


def quaternion(r: np.ndarray) -> list[float]:
    """Rotation matrix → pybullet quaternion (x, y, z, w)."""
    return _quaternion(np.asarray(r, dtype=float))


def densify(path: np.ndarray, step_rad: float, step_m: float) -> np.ndarray:
    """Waypoints subdivided so no joint moves more than ``step_rad`` and the TCP no more than ``step_m``."""
    path = np.asarray(path, dtype=float)
    if len(path) < 2:
        return path
    tcp = tcp_pose(path)[0]
    out = [path[:1]]
    for i in range(len(path) - 1):
        dq = np.abs(path[i + 1] - path[i]).max()
        dx = float(np.linalg.norm(tcp[i + 1] - tcp[i]))
        n = max(1, math.ceil(max(dq / step_rad, dx / step_m)))
        t = np.linspace(0, 1, n + 1)[1:, None]
        out.append(path[i] + t * (path[i + 1] - path[i]))
    return np.concatenate(out)


class MotionPlanner:
    """Plans joint-space transfers in a :class:`PlanningWorld` with OMPL's RRTConnect."""

    def __init__(self, world: PlanningWorld) -> None:
        self.world = world
        self.config = world.config

    def plan(
        self, start: np.ndarray, goal: np.ndarray, seed: int, candidates: Sequence[np.ndarray] = ()
    ) -> PlanResult:
        """A collision-free path ``start → goal`` or the failure status; deterministic in ``seed``.

        ``candidates`` are waypoint paths (start first, goal last) worth trying before a search, such
        as the palletiser's lift-over-the-pile-and-descend move; the first collision-free one wins.
        """
        world, cfg = self.world, self.config
        t0 = perf_counter()
        world.checks = 0
        world._limit = cfg.max_checks
        start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
        try:
            if world.in_collision(start):
                return PlanResult(np.stack([start, goal]), "start_invalid", world.checks, perf_counter() - t0)
            if world.in_collision(goal):
                return PlanResult(np.stack([start, goal]), "goal_invalid", world.checks, perf_counter() - t0)
            if world.segment_free(start, goal):
                return PlanResult(np.stack([start, goal]), "direct", world.checks, perf_counter() - t0)
            for candidate in candidates:
                candidate = np.asarray(candidate, dtype=float)
                if all(world.segment_free(a, b) for a, b in zip(candidate[:-1], candidate[1:], strict=True)):
                    return PlanResult(candidate, "via", world.checks, perf_counter() - t0)
            path = None
            attempt = 0
            while path is None and world.checks < cfg.max_checks - cfg.simplify_checks:
                path = self._rrt(start, goal, seed + attempt)
                attempt += 1
        except _Budget:
            path = None
        finally:
            world._limit = 0
        if path is None:
            return PlanResult(np.stack([start, goal]), "failed", world.checks, perf_counter() - t0)
        return PlanResult(path, "planned", world.checks, perf_counter() - t0)

    def _rrt(self, start: np.ndarray, goal: np.ndarray, seed: int) -> np.ndarray | None:
        world, cfg = self.world, self.config
        level = ou.getLogLevel()
        ou.setLogLevel(ou.LOG_NONE)  # setSeed warns on every call after the first; the reseed still holds
        ou.RNG.setSeed(int(seed) % (2**31 - 1) or 1)
        ou.setLogLevel(level)
        space = ob.RealVectorStateSpace(6)
        bounds = ob.RealVectorBounds(6)
        for j in range(6):
            lo, hi = float(LOWER[j]), float(UPPER[j])
            if j in (3, 5):  # the wrist turns need not be explored beyond a turn around the ends
                lo = max(lo, min(start[j], goal[j]) - math.pi)
                hi = min(hi, max(start[j], goal[j]) + math.pi)
            bounds.setLow(j, lo)
            bounds.setHigh(j, hi)
        space.setBounds(bounds)
        setup = og.SimpleSetup(space)
        budget_over = [False]

        def valid(state: object) -> bool:
            if budget_over[0]:
                return False
            try:
                return not world.in_collision([state[i] for i in range(6)])  # type: ignore[index]
            except _Budget:
                budget_over[0] = True
                return False

        setup.setStateValidityChecker(valid)
        info = setup.getSpaceInformation()
        info.setStateValidityCheckingResolution(cfg.search_step_rad / space.getMaximumExtent())
        s, g = space.allocState(), space.allocState()
        for j in range(6):
            s[j], g[j] = float(start[j]), float(goal[j])
        setup.setStartAndGoalStates(s, g)
        planner = og.RRTConnect(info)
        planner.setRange(cfg.rrt_range)
        setup.setPlanner(planner)
        search_limit = cfg.max_checks - cfg.simplify_checks
        status = setup.solve(
            ob.PlannerTerminationCondition(lambda: budget_over[0] or world.checks >= search_limit)
        )
        if not setup.haveExactSolutionPath() or "Exact" not in str(status):
            return None
        path = setup.getSolutionPath()
        simplify_limit = world.checks + cfg.simplify_checks
        setup.getPathSimplifier().simplify(
            path, ob.PlannerTerminationCondition(lambda: budget_over[0] or world.checks >= simplify_limit)
        )
        states = np.array([[path.getState(i)[j] for j in range(6)] for i in range(path.getStateCount())])
        states[0], states[-1] = start, goal
        # Dense re-check of what OMPL checked at the coarser search resolution.
        for a, b in zip(states[:-1], states[1:], strict=True):
            if not world.segment_free(a, b):
                return None
        return states
