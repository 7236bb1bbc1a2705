"""Physics Pack (docs/benchmark.md, "Settings"): the box is released at rest just above where the *physical* pile lets it
rest, the world settles, and the policy sees where everything actually ended up."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import fields, replace

import numpy as np

from robobpp.core import Action, Box, ContainerState, EpisodeSpec, FinalBox, Infeasible, Placement, box_label
from robobpp.sim.base import Setting, StepOutcome
from robobpp.sim.physics.config import PhysicsConfig
from robobpp.sim.physics.geometry import aabbs, clear_shift, observed_heightmap, surface_height
from robobpp.sim.physics.recording import PoseRecorder
from robobpp.sim.physics.settle import Displacement, Settler, SettleReport, detect_collapse
from robobpp.sim.physics.world import PhysicsWorld, WorldBox

#: Rounding of the per-step ``extra["poses"]``: 0.01 cm (0.1 mm) and 1e-5 for quaternion components. The
#: trace is for replay; the metrics read the unrounded poses.
POSE_CM_DIGITS = 2
POSE_QUAT_DIGITS = 5


class PhysicsPack(Setting):
    """One fresh pybullet client per episode, so the same episode always gives the same figures.

    Options are :class:`PhysicsConfig` fields (``PhysicsPack(mode="full")``) or a whole ``config``.
    """

    name = "physics"
    #: Record how boxes move during each step (``extra["track"]``) for the replay; reading poses only,
    #: it changes no outcome. Off saves the samples' small cost where no trace is kept.
    record_tracks: bool = True
    #: Refuse a placement whose top would stand above the container on the pile *as it physically is*
    #: (``too_high``). The paper protocol turns it off: there, as in the reference, the height was checked on
    #: the plan's idealised pile (``robobpp.replay.OpenLoop``) and the box goes where the pile takes it.
    height_check: bool = True

    def __init__(self, config: PhysicsConfig | None = None, **options: object) -> None:
        known = {f.name for f in fields(PhysicsConfig)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ValueError(
                f"unknown physics option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
            )
        self.config = replace(config or PhysicsConfig(), **options)  # type: ignore[arg-type]
        self.world: PhysicsWorld | None = None
        self.spec: EpisodeSpec | None = None
        self._boxes: list[WorldBox] = []
        self._planned: list[Placement] = []
        self._state: ContainerState | None = None
        self.recorder: PoseRecorder | None = None

    # -- Setting -------------------------------------------------------------------------------------
    @property
    def physics_version(self) -> str:
        return self.config.version

    def reset(self, spec: EpisodeSpec) -> None:
        self.close()
        self.spec = spec
        self.world = PhysicsWorld(self.config)
        self.world.add_pallet(spec.container)
        self._settler = Settler(self.world)
        self.recorder = PoseRecorder(self.world) if self.record_tracks else None
        self._boxes = []
        self._planned = []
        self._state = None

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
            self.world = None

    def _world(self) -> PhysicsWorld:
        if self.world is None or self.spec is None:
            raise RuntimeError("PhysicsPack: reset(spec) first")
        return self.world

    def resting_height(self, x: float, y: float, length: float, width: float) -> float:
        """Where a footprint released from above meets the pile as it physically is now, cm."""
        world = self._world()
        centers, quats, halves = world.poses_cm(self._boxes)
        return surface_height(
            centers, quats, halves, x, y, x + length, y + width, self.config.edge_tolerance_cm
        )

    def apply(self, box: Box, action: Action, index: int) -> StepOutcome:
        target = self.target_placement(box, action, index)
        if isinstance(target, Infeasible):
            return StepOutcome(None, target)
        report = self.release_and_settle(target, box.mass)
        return self.finish_placement(report)

    # -- the placement procedure, shared with the Execution Pack -------------------------------------
    # A subclass that moves the box there some other way (a robot) calls these three in order, so the
    # release, the settle, the collapse check and the outcome are built in one place only.
    @property
    def boxes(self) -> tuple[WorldBox, ...]:
        """The released boxes' bodies, in placement order (read-only view)."""
        return tuple(self._boxes)

    @property
    def planned(self) -> tuple[Placement, ...]:
        """Where each released box was meant to rest, in placement order (read-only view)."""
        return tuple(self._planned)

    def target_placement(self, box: Box, action: Action, index: int) -> Placement | Infeasible:
        """The planned placement: the action's (x, y) at the resting height the *physical* pile offers,
        or ``Infeasible("too_high")`` when the box's top would then stand above the container (unless
        ``height_check`` is off)."""
        self._world()  # refuses before reset
        spec = self.spec
        assert spec is not None
        length, width, height = box.dims(action.orientation)
        z = self.resting_height(action.x, action.y, length, width)
        if self.height_check and z + height > spec.container.height + self.config.too_high_slack_cm:
            detail = (
                f"box top at {z + height:g} cm would exceed the container height {spec.container.height:g} cm"
            )
            return Infeasible("too_high", detail)
        return Placement(action.x, action.y, z, length, width, height, action.orientation, index)

    def release_and_settle(
        self, planned: Placement, mass: float, disturbed: Sequence[WorldBox] = ()
    ) -> SettleReport:
        """Land the box on ``planned`` (``PhysicsConfig.release``: lowered until it touches, or let go at rest
        ``release_gap_cm`` above) and settle the world.

        ``disturbed``: boxes something else already set moving (the robot's arm); they are simulated
        from the start like the new box.
        """
        world = self._world()
        cfg = self.config
        cx, cy, cz = planned.center
        if cfg.release_clear:
            dx, dy = self._clearance(planned)
            cx, cy = cx + dx, cy + dy
        extents = (planned.length, planned.width, planned.height)
        body_mass = mass if cfg.box_mass_kg is None else cfg.box_mass_kg
        above = cfg.lower_from_cm if cfg.release == "lower" else cfg.release_gap_cm
        new = world.add_box((cx, cy, cz + above), extents, body_mass)
        if cfg.release == "lower":  # the reference's landing; Static Stability's window starts at the touch
            world.lower_until_contact(new, above, cfg.lower_step_cm)
        self._boxes.append(new)
        self._planned.append(planned)
        self._state = None
        return self._settler.run([new, *disturbed], self.recorder)

    def withdraw_last(self) -> None:
        """Take the last released box out of the world and out of the episode's count: the reference ends
        an episode on an operation it does not count (its third dangerous operation) this way."""
        world = self._world()
        box = self._boxes.pop()
        self._planned.pop()
        world.remove_box(box)
        self._state = None

    def _clearance(self, planned: Placement) -> tuple[float, float]:
        """Horizontal shift (cm) that releases ``planned`` clear of the placed boxes reaching into its
        footprint above its resting height (by less than the edge tolerance, which ``resting_height``
        ignores); (0, 0) when nothing is in the way or no shift of at most that size clears it all."""
        centers, quats, halves = self._world().poses_cm(self._boxes)
        lo, hi = aabbs(centers, quats, halves)
        return clear_shift(
            lo,
            hi,
            planned,
            self.config.release_gap_cm,
            self.config.edge_tolerance_cm,
            self.config.clear_gap_cm,
        )

    def finish_placement(
        self,
        report: SettleReport,
        *,
        trajectory_length_m: float | None = None,
        dangerous: bool | None = None,
        extra: Mapping[str, object] | None = None,
    ) -> StepOutcome:
        """Collapse check after the last release and the step's outcome (settle figures in ``extra``,
        then the caller's ``extra``)."""
        spec = self.spec
        assert spec is not None and self._planned
        index = self._planned[-1].index
        moved = self._displaced()
        actual = self._actual(len(self._boxes) - 1)
        info: dict[str, object] = {
            "sim_steps": report.steps,
            "at_rest": report.at_rest,
            "simulated_boxes": report.simulated_boxes,
            "max_linear_speed": report.max_linear,
            "max_angular_speed": report.max_angular,
        }
        info.update(extra or {})
        info["poses"] = self.compact_poses()
        track = None if self.recorder is None else self.recorder.take(self._boxes)
        if track is not None:
            info["track"] = track
        termination = None
        if moved:
            worst = max(moved, key=lambda d: (d.fell, d.horizontal_cm))
            others = f"; {len(moved)} boxes in all moved past the threshold or fell" if len(moved) > 1 else ""
            termination = Infeasible(  # the worst box first: "after placing box #37 (the 38th), box #12 ..."
                "collapse",
                f"after placing {box_label(index)}, {worst.describe(spec.collapse_threshold_cm)}{others}",
            )
            info["collapsed_boxes"] = [d.index for d in moved]
        return StepOutcome(
            actual,
            termination,
            static_stability=report.static_stability,
            collapsed=bool(moved),
            trajectory_length_m=trajectory_length_m,
            dangerous=dangerous,
            extra=info,
        )

    def compact_poses(self) -> list[list[float]]:
        """Every released box's actual pose now, for the replay trace: ``[x, y, z, qx, qy, qz, qw]`` per box
        in placement order (= box index), the *centre* in cm rounded to 0.1 mm and the attitude relative
        to how it was placed rounded to 1e-5. Plain floats, so the trace stays JSON."""
        centers, quats, _ = self._world().poses_cm(self._boxes)
        return [
            [round(float(v), POSE_CM_DIGITS) for v in c] + [round(float(v), POSE_QUAT_DIGITS) for v in q]
            for c, q in zip(centers, quats, strict=True)
        ]

    def _displaced(self) -> list[Displacement]:
        assert self.spec is not None
        targets = np.array([p.center for p in self._planned]).reshape(-1, 3)
        indices = [p.index for p in self._planned]
        return detect_collapse(self._world(), self._boxes, targets, indices, self.spec.collapse_threshold_cm)

    def _actual(self, i: int, resolution: float = 0.0) -> Placement:
        """Box ``i`` where it is: its centre as measured written as a min corner, rounded to ``resolution``
        cm (the observation) or not (0: outcomes and metrics)."""
        centre, quat = self._world().pose_cm(self._boxes[i])
        planned = self._planned[i]
        corner = (
            centre[0] - planned.length / 2,
            centre[1] - planned.width / 2,
            centre[2] - planned.height / 2,
        )
        if resolution > 0:
            x, y, z = (round(round(c / resolution) * resolution, 6) for c in corner)
            corner = (x, y, z)
        return Placement(
            *corner,
            planned.length,
            planned.width,
            planned.height,
            planned.orientation,
            planned.index,
            quat,
        )

    def state(self) -> ContainerState:
        """Actual poses (centre-based min corner + quaternion, rounded as ``pose_resolution_cm`` says) and the
        heightmap of their bounds (``observed_heightmap``)."""
        self._world()
        if self._state is None:
            assert self.spec is not None
            state = ContainerState(self.spec.container)
            step = self.config.pose_resolution_cm
            state.placements = [self._actual(i, step) for i in range(len(self._boxes))]
            state.heightmap = observed_heightmap(
                state.heightmap.shape,
                state.placements,
                self.config.heightmap_shrink_cm,
                self.config.heightmap_resolution_cm,
            )
            self._state = state
        return self._state

    def plan(self) -> list[Placement]:
        """Where each released box was meant to rest (what ``final_boxes`` pairs with the actual poses, without
        reading the world again)."""
        return list(self._planned)

    def final_boxes(self) -> list[FinalBox]:
        """Planned vs actual pose; ``in_place`` = within the collapse threshold and still on the pallet."""
        moved = {d.index for d in self._displaced()}
        return [
            FinalBox(planned, self._actual(i), planned.index not in moved)
            for i, planned in enumerate(self._planned)
        ]
