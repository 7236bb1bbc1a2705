"""Execution Pack (docs/benchmark.md, "Settings"): the Physics Pack with an IRB 6700 doing every placement.

Per box: suction grasp from the top at the conveyor (capacity check), vertical lift, a transfer planned
with OMPL in a separate planning world (static copies of the placed boxes, the carried box attached),
vertical descent, release, the Physics Pack's settle and collapse check, retreat. The arm (kinematic:
zero mass, driven along the time-parameterised trajectory) and the carried box (kinematic too) move
through the physical world, so a bad path pushes placed boxes. Boxes the motion touches are woken and
simulated; while nothing is near, the arm just moves (resting boxes that nothing touches cannot move).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import numpy as np
import pybullet as p

from robobpp.core import Action, Box, EpisodeSpec, Infeasible, Placement, box_label
from robobpp.sim.base import StepOutcome
from robobpp.sim.execution import motion, recording
from robobpp.sim.execution.layout import Layout
from robobpp.sim.physics import PhysicsConfig, PhysicsPack
from robobpp.sim.physics.config import versioned
from robobpp.sim.physics.world import CM, PALLET_HEIGHT_M, WorldBox
from robobpp.sim.planner import MotionPlanner, PlannerConfig, PlanningWorld, Vector, quaternion
from robobpp.sim.robot.facts import TOOL
from robobpp.sim.robot.kinematics import joint_frames, rot, tcp_pose
from robobpp.sim.robot.urdf import LINK_NAMES, urdf_path


@dataclass(frozen=True, slots=True)
class ExecutionConfig:
    """Robot-side parameters; recorded with the run like :class:`PhysicsConfig`."""

    #: A pick-to-place operation whose time-parameterised execution takes longer than this is unsafe.
    safe_time_s: float = 3.0
    #: TCP speed cap on the Cartesian segments (lift, descent), m/s.
    cartesian_speed: float = 0.5
    #: Suction capacity, kg per m² of grasped top area.
    capacity_kg_m2: float = TOOL.capacity_kg_m2
    #: Ends the episode on a failed grasp; by default it only counts as dangerous (a policy can change
    #: neither a box's mass nor its top area, so it should not lose the episode for it).
    end_on_failed_grasp: bool = False
    #: Added to the episode seed for the planner's RNG (recorded per placement).
    seed: int = 0
    #: Horizontal margin (m) around a robot link or the carried box within which resting boxes are
    #: woken and the world is stepped during the motion.
    wake_margin_m: float = 0.05
    #: The carried box's collision shape (physical and planning world) is this much smaller (cm) on each
    #: vertical side; the box released at the target has its full size. Policies place on a 1 cm grid
    #: beside boxes of non-integer size, so a chosen slot often overlaps a neighbour by up to 5 mm (the
    #: Physics Pack's ``edge_tolerance_cm``, under which it ignores such overlap), and settling shifts
    #: boxes by millimetres. A full-size kinematic box lowered into such a slot shoved the neighbour
    #: (and the row behind it) by centimetres, which the Physics Pack's release does not; with the
    #: margin the robot delivers the box and the release resolves the overlap as in the Physics Pack.
    carried_margin_cm: float = 0.5
    #: The pre-place pose, where the planned transfer ends and the vertical descent begins, has the TCP
    #: (the top of the carried box) this high (m) above the target's centre, as the reference plans its
    #: place move (its tool tip to the target's centre + 0.35 m); at least ``Layout.approach`` above the
    #: release pose. Where the arm cannot reach that high (the top of the 1.7 m Diverse stack), the
    #: highest reachable height in 5 cm steps is used: the layout reaches every placement, and a failed
    #: place plan must mean the robot cannot place the box, not that the pre-place pose is out of reach.
    place_height_m: float = 0.35
    #: A place plan that cannot even start ends the episode, the box not placed, as the reference's
    #: "Move_ee_to fail" does: no IK solution (``unreachable``), or the arm with its box in collision at
    #: the pre-place pose or at the start (``no_path:goal_invalid``, ``no_path:start_invalid``). False:
    #: such an operation is only dangerous and the box is still placed (physics version 3's rule).
    end_on_failed_place: bool = True
    #: The episode ends at this many dangerous operations, the last box not counted (the reference ends
    #: at its third); 0 never ends it. Failed grasps do not count towards it (a policy can change
    #: neither a box's mass nor its top area; the reference has no grasp capacity), only the robot's
    #: motion: no path within the budget, a blocked descent, a slow operation.
    dangerous_limit: int = 3
    #: Experiment only: False stops the robot at the pre-place pose and lets the box go there, the
    #: Physics Pack then releasing it at its target, as the reference teleports the released box and
    #: lowers it onto the pile. The benchmark's robot descends (docs/benchmark.md, "Settings").
    descend: bool = True
    #: Experiment only: the carried box is turned by this yaw (degrees) on the tool during the transfer.
    #: The reference grasps with the tool turned by its first yaw try (90°) and plans its place move with
    #: the tool unturned, so its box hangs 90° off its target until the teleport; only with ``descend``
    #: False (a turned box cannot be lowered into its slot).
    carried_yaw_deg: float = 0.0
    #: Experiment only: a place plan whose search ends without an exact path (its pre-place pose in
    #: collision, or its budget spent) is accepted as the reference accepts its planner's approximate
    #: solution: the robot stops short of the pose on a collision-free path, releases the box and it is
    #: put at its target (no unchecked motion through the pile, no ending). It is dangerous only where
    #: the reference's search, run to its time limit for that placement (:func:`search_time_limit_s`),
    #: would pass its 15 s threshold; then the robot moves unchecked as with the default rule.
    approximate_plans: bool = False
    #: Experiment only (0: off): the pre-place pose holds the carried box's bottom this far (m) above where it
    #: will rest, instead of ``place_height_m`` above the target's centre. The reference's tool tip goes 0.35 m
    #: above a target point that lies half a box height plus about 2.5 cm above the box's resting centre, so its
    #: box hangs about 0.375 m above its resting place whatever its height (measured running it).
    place_clearance_m: float = 0.0
    planner: PlannerConfig = field(default_factory=PlannerConfig)

    def __post_init__(self) -> None:
        for name in ("safe_time_s", "cartesian_speed", "capacity_kg_m2", "place_height_m"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"execution {name} must be finite and > 0, got {value!r}")
        if not math.isfinite(self.carried_margin_cm) or not 0 <= self.carried_margin_cm <= 2:
            raise ValueError(
                f"execution carried_margin_cm must be in [0, 2] cm, got {self.carried_margin_cm!r}"
            )
        if self.carried_yaw_deg and self.descend:
            raise ValueError("execution carried_yaw_deg needs descend=False (a turned box cannot be lowered)")
        if not isinstance(self.dangerous_limit, int) or self.dangerous_limit < 0:
            raise ValueError(f"execution dangerous_limit must be an int >= 0, got {self.dangerous_limit!r}")

    def to_dict(self) -> dict[str, object]:
        return asdict(self)

    def changed(self) -> dict[str, object]:
        """The robot settings that differ from the benchmark's robot."""
        return {k: v for k, v in self.to_dict().items() if v != _ROBOT_DEFAULTS[k]}


_ROBOT_DEFAULTS = ExecutionConfig().to_dict()

#: The reference's time limit for a place search (s) at the first placement, per dataset; it grows by 1 s per
#: placed box up to ``SEARCH_TIME_CAP_S``. A search that finds no exact path runs to this limit, and an
#: operation whose planning takes longer than ``DANGEROUS_PLANNING_S`` is dangerous there.
SEARCH_TIME_BASE_S = {"repetitive": 10.0, "diverse": 10.0, "longboard": 5.0}
SEARCH_TIME_CAP_S = 19.0
DANGEROUS_PLANNING_S = 15.0


def search_time_limit_s(dataset: str, placed: int) -> float:
    """The reference's search time limit for the placement after ``placed`` boxes (``dataset`` unknown to it:
    the Repetitive/Diverse base)."""
    return min(SEARCH_TIME_BASE_S.get(dataset, 10.0) + placed, SEARCH_TIME_CAP_S)


def approximate_is_dangerous(dataset: str, placed: int) -> bool:
    """Whether a search without an exact path, run to the reference's limit, passes its dangerous threshold
    (the limit plus its IK is over 15 s as soon as the limit reaches 15 s)."""
    return search_time_limit_s(dataset, placed) >= DANGEROUS_PLANNING_S


def _split_options(options: dict[str, object]) -> tuple[dict[str, object], dict[str, object]]:
    physics_names = {f.name for f in fields(PhysicsConfig)}
    execution_names = {f.name for f in fields(ExecutionConfig)}
    physics, execution = {}, {}
    for key, value in options.items():
        if key in physics_names:
            physics[key] = value
        elif key in execution_names:
            execution[key] = value
        else:
            raise TypeError(f"unknown Execution Pack option {key!r}")
    return physics, execution


@dataclass(slots=True)
class Operation:
    """What the robot did for one box."""

    trajectory: motion.Trajectory | None
    tcp_length_m: float
    execution_time_s: float
    failed_grasp: bool
    reasons: list[str]
    plan_status: str
    plan_checks: int
    plan_seconds: float
    seed: int
    #: False: the robot does not drive ``trajectory`` through the world (an accepted approximate plan:
    #: it stops short, collision-free, and the box is put at its target).
    driven: bool = True

    @property
    def dangerous(self) -> bool:
        return bool(self.reasons)

    @property
    def motion_dangerous(self) -> bool:
        """Dangerous because of the robot's motion (what counts towards ``dangerous_limit``)."""
        return any(r != "failed_grasp" for r in self.reasons)


#: Dangerous reasons that mean the place plan could not start (the reference's "Move_ee_to fail").
PLACE_FAILURES = frozenset({"unreachable", "no_path:goal_invalid", "no_path:start_invalid"})
#: What ``approximate_plans`` takes out of them: the reference's planner returns an approximate path there.
APPROXIMATE = frozenset({"no_path:goal_invalid"})


class ExecutionPack(PhysicsPack):
    """Physics Pack + robot. Options: :class:`PhysicsConfig` and :class:`ExecutionConfig` field names."""

    name = "execution"

    def __init__(
        self,
        config: PhysicsConfig | None = None,
        execution: ExecutionConfig | None = None,
        layout: Layout | None = None,
        **options: object,
    ) -> None:
        physics, robot = _split_options(options)
        super().__init__(config, **physics)
        self.execution = replace(execution or ExecutionConfig(), **robot)  # type: ignore[arg-type]
        self._layout_override = layout
        self.layout: Layout | None = None
        self.planning: PlanningWorld | None = None
        self.planner: MotionPlanner | None = None
        self.robot = -1
        self.q = np.zeros(6)
        self.last_operation: Operation | None = None
        #: The replay's record of the current operation (``extra["motion"]``), when recording.
        self.motion_record: dict[str, Any] | None = None
        self._cell_recorded = False
        self._dangerous_count = 0

    @property
    def physics_version(self) -> str:
        """The physics version, with a digest when the physics *or the robot* differ from the defaults (an
        experiment's robot, e.g. ``approximate_plans``, never shares a board with the benchmark's)."""
        robot = {f"execution.{k}": v for k, v in self.execution.changed().items()}
        return versioned({**self.config.changed(), **robot})

    # -- lifecycle -----------------------------------------------------------------------------------
    def reset(self, spec: EpisodeSpec) -> None:
        super().reset(spec)
        layout = self._layout_override or Layout(spec.container, floor_z=-PALLET_HEIGHT_M)
        if layout.container != spec.container:
            raise ValueError("the layout was made for another container")
        self.layout = layout
        self._cell_recorded = False
        self._dangerous_count = 0
        world = self._world()
        cid = world.client
        base_quat = p.getQuaternionFromEuler((0, 0, layout.base_yaw))
        self.robot = p.loadURDF(
            urdf_path(), layout.base_position.tolist(), base_quat, useFixedBase=True, physicsClientId=cid
        )
        for link in range(-1, len(LINK_NAMES)):  # kinematic: pushes boxes, is never pushed
            p.changeDynamics(self.robot, link, mass=0.0, physicsClientId=cid)
        conveyor_centre, conveyor_half = layout.conveyor_box()
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=conveyor_half.tolist(), physicsClientId=cid)
        p.createMultiBody(0, shape, -1, conveyor_centre.tolist(), physicsClientId=cid)
        length, width = spec.container.length * CM, spec.container.width * CM
        ground_half = 6.0
        statics: list[tuple[Vector, Vector]] = [
            (conveyor_centre, conveyor_half),
            # pallet (deck and its support, floor to deck top)
            ((length / 2, width / 2, layout.floor_z / 2), (length / 2, width / 2, -layout.floor_z / 2)),
            ((length / 2, width / 2, layout.floor_z - 0.05), (ground_half, ground_half, 0.05)),
        ]
        self.planning = PlanningWorld(layout.base_position, layout.base_yaw, statics, self.execution.planner)
        self.planner = MotionPlanner(self.planning)
        self.q = layout.home
        self._set_arm(self.q)

    def close(self) -> None:
        if self.planning is not None:
            self.planning.close()
            self.planning = None
        super().close()

    # -- helpers -------------------------------------------------------------------------------------
    def _set_arm(self, q: np.ndarray, velocity: np.ndarray | None = None) -> None:
        cid = self._world().client
        for j in range(6):
            v = 0.0 if velocity is None else float(velocity[j])
            p.resetJointState(self.robot, j, float(q[j]), targetVelocity=v, physicsClientId=cid)

    def _carried_half_extents(self, box: Box) -> np.ndarray:
        """Half extents (m, box frame) of the carried box's collision shape: shrunk horizontally by
        ``carried_margin_cm`` per side (see :class:`ExecutionConfig`)."""
        m = self.execution.carried_margin_cm
        return np.array([max(box.length / 2 - m, 0.05), max(box.width / 2 - m, 0.05), box.height / 2]) * CM

    def _seed(self, index: int) -> int:
        assert self.spec is not None
        key = f"{self.spec.episode_id}:{self.spec.seed}:{self.execution.seed}:{index}".encode()
        return int.from_bytes(hashlib.sha256(key).digest()[:4], "little") % (2**31 - 2) + 1

    # -- the operation -------------------------------------------------------------------------------
    def apply(self, box: Box, action: Action, index: int) -> StepOutcome:
        world = self._world()
        assert self.layout is not None
        planned = self.target_placement(box, action, index)
        if isinstance(planned, Infeasible):
            return StepOutcome(None, planned)
        self.motion_record = None
        if self.recorder is not None:
            self.recorder.discard()
        operation = self.plan_operation(box, planned)
        self.last_operation = operation
        failures = PLACE_FAILURES - APPROXIMATE if self.execution.approximate_plans else PLACE_FAILURES
        if self.execution.end_on_failed_place and any(r in failures for r in operation.reasons):
            # Nothing moved: the box is not placed and the operation not counted (dangerous None).
            reasons = ", ".join(r for r in operation.reasons if r in failures)
            detail = f"the robot cannot place {box_label(index)} ({reasons})"
            extra: dict[str, object] = {
                "plan_status": operation.plan_status,
                "plan_checks": operation.plan_checks,
                "planner_seed": operation.seed,
                "dangerous_reasons": list(operation.reasons),
            }
            return StepOutcome(None, Infeasible("place_plan_failed", detail), extra=extra)
        carried, disturbed = self._operate(box, operation)
        # Release: the kinematic carried box gives way to the dynamic one, exactly at the release pose.
        if carried is not None:
            p.removeBody(carried, physicsClientId=world.client)
        if operation.failed_grasp and self.execution.end_on_failed_grasp:
            detail = (
                f"box of {box.mass:g} kg exceeds the suction capacity of its "
                f"{planned.length:g}×{planned.width:g} cm top"
            )
            return StepOutcome(
                None, Infeasible("failed_grasp", detail), dangerous=True, trajectory_length_m=0.0
            )
        # Retreat before the settle (not simulated, outside the trajectory metric): left at the release
        # pose, the tool propped up boxes that tip over in the Physics Pack. The release and the settle
        # are then exactly the Physics Pack's, plus the boxes the motion set moving.
        self.q = self.layout.home
        self._set_arm(self.q)
        if self.recorder is not None and self.motion_record is not None:
            self.recorder.begin(self.motion_record["grip"][1])
        report = self.release_and_settle(planned, box.mass, disturbed)
        extra = {
            "execution_time_s": operation.execution_time_s,
            "plan_status": operation.plan_status,
            "plan_checks": operation.plan_checks,
            "planning_time_s": operation.plan_seconds,
            "planner_seed": operation.seed,
            "dangerous_reasons": list(operation.reasons),
            "failed_grasp": operation.failed_grasp,
            "disturbed_boxes": len(disturbed),
        }
        if operation.trajectory is not None:
            extra["tool_path_cm"] = motion.tool_path_cm(operation.trajectory, self.layout)
        if self.record_tracks:
            if not self._cell_recorded:
                extra["cell"] = recording.cell(self.layout)
                self._cell_recorded = True
            if self.motion_record is not None:
                extra["motion"] = self.motion_record
        outcome = self.finish_placement(
            report, trajectory_length_m=operation.tcp_length_m, dangerous=operation.dangerous, extra=extra
        )
        limit = self.execution.dangerous_limit
        if operation.motion_dangerous:
            self._dangerous_count += 1
            if limit and self._dangerous_count >= limit and outcome.termination is None:
                # The reference checks collapse first, then ends on its third dangerous operation and
                # drops that box from its count.
                self.withdraw_last()
                outcome.placement = None
                outcome.termination = Infeasible(
                    "dangerous_operations",
                    f"dangerous operation number {self._dangerous_count} (the limit) placing {box_label(index)}",
                )
        return outcome

    def plan_operation(self, box: Box, planned: Placement) -> Operation:
        """Grasp check, IK and planning for one box, without touching the physical world."""
        layout, planning, planner = self.layout, self.planning, self.planner
        assert layout is not None and planning is not None and planner is not None
        cfg = self.execution
        seed = self._seed(planned.index)
        reasons: list[str] = []
        failed_grasp = box.mass > cfg.capacity_kg_m2 * (box.length * box.width * CM * CM)
        if failed_grasp:
            reasons.append("failed_grasp")
        # Pick: grasp the top-face centre, box length along the tool's y axis.
        centre, yaw = layout.pick_box_pose(box)
        tcp_pick = centre + np.array([0.0, 0.0, box.height * CM / 2])
        r_pick = layout.tool_rotation(yaw)
        q_grasp = layout.ik(tcp_pick, r_pick, self.q)
        cx, cy, cz = planned.center
        release_centre = np.array([cx, cy, cz + self.config.release_gap_cm]) * CM
        tcp_release = release_centre + np.array([0.0, 0.0, planned.height * CM / 2])
        tcp_lift = tcp_pick + np.array([0.0, 0.0, layout.lift])
        lift = None if q_grasp is None else motion.cartesian_line(layout, q_grasp, tcp_lift)
        tcp_pre, place = tcp_release + np.array([0.0, 0.0, layout.approach]), None
        if lift is not None:
            # From the release TCP: the target centre is half a box height and the release gap below it.
            highest = cfg.place_height_m - (planned.height / 2 + self.config.release_gap_cm) * CM
            if cfg.place_clearance_m:  # experiment: the carried box's bottom that far above its resting place
                highest = cfg.place_clearance_m - self.config.release_gap_cm * CM
            heights = np.arange(highest, layout.approach - 1e-9, -0.05)
            for up in [*heights, layout.approach] if len(heights) else [layout.approach]:
                tcp_pre = tcp_release + np.array([0.0, 0.0, up])
                place = layout.place_ik(tcp_pre, planned.orientation, lift[-1])
                if place is not None:
                    break
        descent = None
        if place is not None:
            descent = (
                motion.cartesian_line(layout, place[0], tcp_release, 0.01) if cfg.descend else place[0][None]
            )
        straight = float(
            np.linalg.norm(tcp_release - tcp_pick) + layout.lift + (tcp_pre[2] - tcp_release[2])
        )  # used when the robot cannot even reach: a lower bound of the path it would need
        if q_grasp is None or lift is None or place is None or descent is None:
            # The reference ignores a failed pick (its box is teleported to the target after release); a
            # target the arm cannot reach ends its episode.
            reasons.append("grasp_unreachable" if q_grasp is None or lift is None else "unreachable")
            return Operation(None, straight, math.inf, failed_grasp, reasons, "unreachable", 0, 0.0, seed)
        # Planning world: static copies of the placed boxes at their actual poses; the box on the tool.
        centers, quats, halves = self._world().poses_cm(list(self.boxes))
        planning.set_obstacles(list(zip(centers * CM, quats, halves * CM, strict=True)))
        r_box = rot("z", yaw + math.radians(cfg.carried_yaw_deg))
        offset = r_pick.T @ (centre - tcp_pick)
        planning.attach(self._carried_half_extents(box), offset, r_pick.T @ r_box)
        candidates = self._over_the_pile(box, tcp_lift, tcp_pre, lift[-1], place[0])
        result = planner.plan(lift[-1], place[0], seed, candidates)
        path = result.path
        driven = True
        if not result.ok:
            assert self.spec is not None
            if (
                cfg.approximate_plans
                and result.status in ("goal_invalid", "failed")
                and not approximate_is_dangerous(self.spec.dataset, planned.index)
            ):
                driven = False  # an approximate plan, accepted: the robot stops short, nothing pushed
            else:
                # The robot then moves unchecked, like the reference: along its default palletiser move.
                reasons.append(f"no_path:{result.status}")
            if candidates:
                path = candidates[0]
        elif cfg.descend and not all(
            planning.segment_free(a, b) for a, b in zip(descent[:-1], descent[1:], strict=True)
        ):  # each 1 cm leg as the arm drives it (joint-interpolated), densely
            reasons.append("descent_blocked")
        planning.detach()
        segments = [(lift, True), (path, False)] + ([(descent, True)] if cfg.descend else [])
        trajectory = motion.build(segments, cfg.cartesian_speed)
        duration = trajectory.duration
        if duration > cfg.safe_time_s:
            reasons.append("slow")
        return Operation(
            trajectory,
            trajectory.tcp_length(),
            duration,
            failed_grasp,
            reasons,
            result.status if driven else f"approximate:{result.status}",
            result.checks,
            result.seconds,
            seed,
            driven,
        )

    def _over_the_pile(
        self, box: Box, tcp_lift: np.ndarray, tcp_pre: np.ndarray, q_lift: np.ndarray, q_pre: np.ndarray
    ) -> list[np.ndarray]:
        """Palletiser moves to try before a search: rise until the carried box clears the pile, swing
        over, go down to the approach pose (joint-interpolated legs)."""
        layout = self.layout
        assert layout is not None
        top = max((pl.top for pl in self.state().placements), default=0.0) * CM
        z_high = max(top, layout.conveyor_height) + box.height * CM + 0.10
        out: list[np.ndarray] = []
        r_lift = layout.base_rotation @ tcp_pose(q_lift)[1]
        r_pre = layout.base_rotation @ tcp_pose(q_pre)[1]
        up_pick = layout.ik(np.array([tcp_lift[0], tcp_lift[1], max(z_high, tcp_lift[2])]), r_lift, q_lift)
        up_place = layout.ik(np.array([tcp_pre[0], tcp_pre[1], max(z_high, tcp_pre[2])]), r_pre, q_pre)
        if up_place is None:
            return out
        # Vertical legs as Cartesian lines, so the carried box does not swing into its neighbours.
        down = motion.cartesian_line(layout, up_place, tcp_pre, 0.05)
        if down is None or motion.joint_time(down[-1], q_pre) > 1e-3:
            return out
        down[-1] = q_pre
        if up_pick is not None:
            rise = motion.cartesian_line(layout, q_lift, layout.to_world(tcp_pose(up_pick)[0]), 0.05)
            if rise is not None and motion.joint_time(rise[-1], up_pick) < 1e-3:
                rise[-1] = up_pick
                out.append(np.concatenate([rise, down]))
        out.append(np.concatenate([q_lift[None, :], down]))
        return out

    def _operate(self, box: Box, operation: Operation) -> tuple[int | None, list[WorldBox]]:
        """Drive the arm and the carried box along the planned operation through the physical world."""
        if operation.trajectory is None or not operation.driven:
            return None, []
        world = self._world()
        cid = world.client
        layout = self.layout
        assert layout is not None
        shape = p.createCollisionShape(
            p.GEOM_BOX, halfExtents=self._carried_half_extents(box).tolist(), physicsClientId=cid
        )
        carried = p.createMultiBody(0, shape, -1, [0, 0, -5], physicsClientId=cid)
        centre, yaw = layout.pick_box_pose(box)
        q_grasp = operation.trajectory.waypoints[0]
        p_tcp, r_tcp = tcp_pose(q_grasp)
        r_world = layout.base_rotation @ r_tcp
        offset = r_world.T @ (centre - layout.to_world(p_tcp))
        r_local = r_world.T @ rot("z", yaw + math.radians(self.execution.carried_yaw_deg))
        if self.recorder is not None:
            self.motion_record = recording.motion_record(
                operation.trajectory,
                layout,
                self.config.dt,
                self.execution.cartesian_speed,
                (offset, r_local),
            )
            self.recorder.begin(self.motion_record["grip"][0])
        disturbed = self._drive(operation.trajectory, carried, offset, r_local)
        return carried, disturbed

    def _drive(
        self, trajectory: motion.Trajectory, carried: int, offset: np.ndarray, r_local: np.ndarray
    ) -> list[WorldBox]:
        """Move arm and carried box along the trajectory at the world's time step; wake and simulate
        resting boxes only when something comes within the margin of them."""
        world = self._world()
        cid = world.client
        layout = self.layout
        assert layout is not None
        dt = self.config.dt
        samples = trajectory.samples(dt)
        positions, rotations = joint_frames(samples)
        tcp_world = layout.to_world(positions[:, 6, :])
        r_world = np.einsum("ij,njk->nik", layout.base_rotation, rotations[:, 6])
        frames_world = layout.to_world(positions)
        box_centres = tcp_world + np.einsum("nij,j->ni", r_world, offset)
        box_reach = float(
            np.linalg.norm(np.asarray(p.getCollisionShapeData(carried, -1, physicsClientId=cid)[0][3]) / 2)
        )
        by_body = {b.body: b for b in self.boxes}
        container = self.spec.container if self.spec else None
        assert container is not None
        top = max((pl.top for pl in self.planned), default=0.0) * CM + 0.3
        lo = np.array([-0.5, -0.5, -1.0])
        hi = np.array([container.length * CM + 0.5, container.width * CM + 0.5, top])
        margin = self.execution.wake_margin_m
        awake: list[WorldBox] = []
        velocity_scale = 1.0 / dt
        last = samples[0]
        for k in range(len(samples)):
            q = samples[k]
            near_pile = bool(
                np.all(box_centres[k] + box_reach >= lo) and np.all(box_centres[k] - box_reach <= hi)
            ) or bool(np.any(np.all((frames_world[k] >= lo) & (frames_world[k] <= hi), axis=1)))
            if not near_pile and not awake:
                last = q
                continue
            self._set_arm(q, (q - last) * velocity_scale)
            last = q
            quat = quaternion(r_world[k] @ r_local)
            p.resetBasePositionAndOrientation(carried, box_centres[k].tolist(), quat, physicsClientId=cid)
            for body_id, _link in self._overlaps(carried, margin):
                box = by_body.get(body_id)
                if box is not None and box.frozen:
                    world.unfreeze(box)
                    awake.append(box)
            if awake:
                for box in list(awake):
                    (vx, vy, vz), _ = p.getBaseVelocity(box.body, physicsClientId=cid)
                    if vx * vx + vy * vy + vz * vz > self.config.wake_speed**2:
                        for body_id, _link in self._aabb_overlaps(
                            box.body, -1, self.config.wake_margin_cm * CM
                        ):
                            other = by_body.get(body_id)
                            if other is not None and other.frozen:
                                world.unfreeze(other)
                                awake.append(other)
                p.stepSimulation(physicsClientId=cid)
                if self.recorder is not None:
                    self.recorder.sample(k, awake)
        if self.recorder is not None and awake:
            self.recorder.sample(len(samples) - 1, awake, force=True)
        self._set_arm(samples[-1])
        self.q = samples[-1]
        return awake

    def _aabb_overlaps(self, body: int, link: int, margin: float) -> list[tuple[int, int]]:
        cid = self._world().client
        lo, hi = p.getAABB(body, link, physicsClientId=cid)
        found = p.getOverlappingObjects(
            [c - margin for c in lo], [c + margin for c in hi], physicsClientId=cid
        )
        return list(found or [])

    def _overlaps(self, carried: int, margin: float) -> list[tuple[int, int]]:
        out = self._aabb_overlaps(carried, -1, margin)
        for link in range(len(LINK_NAMES) - 1):
            out.extend(self._aabb_overlaps(self.robot, link, margin))
        return out
