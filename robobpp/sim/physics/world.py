"""A PyBullet world for the pallet and the boxes: one DIRECT client per world, never the global one.

The world frame is the container frame in metres (origin at the pallet's top corner, x along the length,
y along the width, z up), so the Execution Pack can put its robot and conveyor into the same world. Box
methods speak centimetres like the rest of robobpp and convert at this boundary.

Friction: Bullet multiplies the two bodies' coefficients for a contact, so every body gets
``sqrt(lateral_friction)`` and each box–box and box–pallet pair then has exactly ``lateral_friction``.
Every body carries a friction anchor (``PhysicsConfig.friction_anchor``): a contact point that sticks keeps
its position, so static friction holds a resting pile in place instead of letting it creep.
"""

from __future__ import annotations

import contextlib
import math
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np
import pybullet as p

from robobpp.core import ContainerSpec
from robobpp.sim.physics.config import PhysicsConfig

CM = 0.01
#: Pallet deck thickness and the height of its top above the ground, m. Boxes that fall off the pallet
#: land on the ground and stay in the simulation (a fall is then seen as z below the deck).
PALLET_THICKNESS_M = 0.05
PALLET_HEIGHT_M = 0.15
WALL_THICKNESS_M = 0.02
#: Bullet's collision margin of a mesh loaded from a URDF, m: the surface Bullet collides lies this far outside
#: the mesh. Each box mesh is made this much smaller on every side, so a box collides at its real size.
MESH_MARGIN_M = 0.001

#: A unit cube centred on its origin, as a Wavefront mesh: the shape every box collides as when
#: ``PhysicsConfig.collision_shape`` is ``mesh``, scaled to the box by the URDF that loads it.
UNIT_CUBE_OBJ = (
    "".join(f"v {x} {y} {z}\n" for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5))
    + "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n"
)


@dataclass(slots=True)
class WorldBox:
    """A box body and what the world needs to know about it (extents along its own axes, cm)."""

    body: int
    half_extents_cm: tuple[float, float, float]
    mass: float
    frozen: bool = False


class PhysicsWorld:
    """Owns a pybullet DIRECT client; several worlds coexist in one process without sharing state."""

    def __init__(self, config: PhysicsConfig | None = None) -> None:
        self.config = config or PhysicsConfig()
        self.client: int = p.connect(p.DIRECT)
        if self.client < 0:
            raise RuntimeError("pybullet could not open a DIRECT client")
        cid = self.client
        p.resetSimulation(physicsClientId=cid)
        p.setGravity(0, 0, -self.config.gravity, physicsClientId=cid)
        p.setTimeStep(self.config.dt, physicsClientId=cid)
        p.setPhysicsEngineParameter(
            numSolverIterations=self.config.solver_iterations,
            deterministicOverlappingPairs=1,
            physicsClientId=cid,
        )
        self.boxes: list[WorldBox] = []
        self.static_bodies: list[int] = []
        self.container: ContainerSpec | None = None
        self._shapes: dict[tuple[float, float, float], int] = {}
        self._mesh_dir: Path | None = None
        self._body_friction = math.sqrt(self.config.lateral_friction)
        self._body_restitution = math.sqrt(self.config.restitution)

    # -- lifecycle -----------------------------------------------------------------------------------
    def close(self) -> None:
        if self.client >= 0:
            with contextlib.suppress(p.error):  # already gone
                p.disconnect(physicsClientId=self.client)
            self.client = -1
        if self._mesh_dir is not None:
            shutil.rmtree(self._mesh_dir, ignore_errors=True)
            self._mesh_dir = None

    def __enter__(self) -> PhysicsWorld:
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        self.close()

    def __del__(self) -> None:  # a forgotten world must not leak its client
        with contextlib.suppress(Exception):  # interpreter shutdown
            self.close()

    # -- static scene --------------------------------------------------------------------------------
    def _surface(self, body: int) -> None:
        p.changeDynamics(
            body,
            -1,
            lateralFriction=self._body_friction,
            restitution=self._body_restitution,
            frictionAnchor=int(self.config.friction_anchor),
            physicsClientId=self.client,
        )

    def _mesh_urdf(self, size_m: tuple[float, float, float]) -> str:
        """A URDF file of one box collision mesh of ``size_m``. Loaded through a URDF as the reference loads its
        boxes: Bullet then reports a touch 1-2 mm before the surfaces meet, where the same convex mesh
        made by ``createCollisionShape`` reports it 3-7 mm before (measured; docs/validation/physics.md, "Static
        Stability against the reference"), and that distance is the landing's fall."""
        if self._mesh_dir is None:
            self._mesh_dir = Path(tempfile.mkdtemp(prefix="robobpp-boxes-"))
            (self._mesh_dir / "cube.obj").write_text(UNIT_CUBE_OBJ)
        path = self._mesh_dir / "box-{:.6f}-{:.6f}-{:.6f}.urdf".format(*size_m)
        if not path.exists():
            sx, sy, sz = size_m
            path.write_text(
                '<robot name="box"><link name="box"><inertial><mass value="1"/>'
                '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial><collision><geometry>'
                f'<mesh filename="{self._mesh_dir / "cube.obj"}" scale="{sx!r} {sy!r} {sz!r}"/>'
                "</geometry></collision></link></robot>"
            )
        return str(path)

    def _body(
        self,
        half_m: tuple[float, float, float],
        center_m: tuple[float, float, float],
        mass: float,
        quaternion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0),
    ) -> int:
        """A box body of half extents ``half_m``: static when ``mass`` is 0, shaped per ``collision_shape``."""
        cid = self.client
        if self.config.collision_shape == "mesh":
            size = (
                2 * (half_m[0] - MESH_MARGIN_M),
                2 * (half_m[1] - MESH_MARGIN_M),
                2 * (half_m[2] - MESH_MARGIN_M),
            )
            body = p.loadURDF(
                self._mesh_urdf(size), center_m, quaternion, useFixedBase=mass == 0, physicsClientId=cid
            )
            if mass > 0:  # the inertia follows the mass (Bullet recomputes it from the shape)
                p.changeDynamics(body, -1, mass=mass, physicsClientId=cid)
            return int(body)
        shape = self._shapes.get(half_m)
        if shape is None:
            shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half_m, physicsClientId=cid)
            self._shapes[half_m] = shape
        return int(p.createMultiBody(mass, shape, -1, center_m, quaternion, physicsClientId=cid))

    def _static_box(self, half_m: tuple[float, float, float], center_m: tuple[float, float, float]) -> int:
        body = self._body(half_m, center_m, 0.0)
        self._surface(body)
        self.static_bodies.append(body)
        return body

    def add_pallet(self, container: ContainerSpec, walls: bool | None = None) -> None:
        """The pallet deck (top at z = 0, the container's footprint), the ground, and optional walls."""
        if self.container is not None:
            raise RuntimeError("this world already has a pallet")
        self.container = container
        length, width, height = container.length * CM, container.width * CM, container.height * CM
        plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=self.client)
        ground = p.createMultiBody(0, plane, -1, (0, 0, -PALLET_HEIGHT_M), physicsClientId=self.client)
        self._surface(ground)
        self.static_bodies.append(ground)
        t = PALLET_THICKNESS_M
        self._static_box((length / 2, width / 2, t / 2), (length / 2, width / 2, -t / 2))
        if walls if walls is not None else self.config.walls:
            w = WALL_THICKNESS_M
            self._static_box((w / 2, width / 2 + w, height / 2), (-w / 2, width / 2, height / 2))
            self._static_box((w / 2, width / 2 + w, height / 2), (length + w / 2, width / 2, height / 2))
            self._static_box((length / 2, w / 2, height / 2), (length / 2, -w / 2, height / 2))
            self._static_box((length / 2, w / 2, height / 2), (length / 2, width + w / 2, height / 2))

    # -- boxes ---------------------------------------------------------------------------------------
    def add_box(
        self,
        center_cm: tuple[float, float, float],
        extents_cm: tuple[float, float, float],
        mass: float,
        quaternion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0),
    ) -> WorldBox:
        """A dynamic box of ``extents_cm`` (along its own x, y, z), centred at ``center_cm``."""
        half = (extents_cm[0] * CM / 2, extents_cm[1] * CM / 2, extents_cm[2] * CM / 2)
        body = self._body(half, (center_cm[0] * CM, center_cm[1] * CM, center_cm[2] * CM), mass, quaternion)
        self._surface(body)
        p.changeDynamics(
            body,
            -1,
            linearDamping=self.config.linear_damping,
            angularDamping=self.config.angular_damping,
            physicsClientId=self.client,
        )
        box = WorldBox(body, (extents_cm[0] / 2, extents_cm[1] / 2, extents_cm[2] / 2), mass)
        self.boxes.append(box)
        return box

    def lower_until_contact(self, box: WorldBox, drop_cm: float, step_cm: float) -> int:
        """The reference's landing: from where it stands, move ``box`` down ``step_cm`` per simulation step
        (its pose set, the world stepped) until something touches it from below, at most ``drop_cm`` plus
        5 cm; the box keeps the speed of its last step. Returns the steps taken.

        Only a touch from below ends it: the reference's grid is 2 % wider than its boxes, so its first touch
        is always what carries the box; ours has no gap, and a neighbour's side, reported 1-2 mm away,
        would end the lowering 1.7 cm up and drop the box from there."""
        cid = self.client
        (x, y, z), orn = p.getBasePositionAndOrientation(box.body, physicsClientId=cid)
        limit = math.ceil((drop_cm + 5.0) / step_cm)
        for n in range(1, limit + 1):
            p.resetBasePositionAndOrientation(
                box.body, (x, y, z - n * step_cm * CM), orn, physicsClientId=cid
            )
            p.stepSimulation(physicsClientId=cid)
            # contactNormalOnB points from the other body to this box: up for a touch from below.
            if any(c[7][2] > 0.5 for c in p.getContactPoints(bodyA=box.body, physicsClientId=cid)):
                return n
        return limit

    def remove_box(self, box: WorldBox) -> None:
        """Take a box out of the world."""
        p.removeBody(box.body, physicsClientId=self.client)
        self.boxes.remove(box)

    def freeze(self, box: WorldBox) -> None:
        """Make the box static where it stands (zero mass); it still collides but no longer moves."""
        if not box.frozen:
            p.changeDynamics(box.body, -1, mass=0.0, physicsClientId=self.client)
            p.resetBaseVelocity(box.body, (0, 0, 0), (0, 0, 0), physicsClientId=self.client)
            box.frozen = True

    def unfreeze(self, box: WorldBox) -> None:
        """Give the box its mass back (at rest) so it takes part in the dynamics again."""
        if box.frozen:
            p.changeDynamics(box.body, -1, mass=box.mass, physicsClientId=self.client)
            p.resetBaseVelocity(box.body, (0, 0, 0), (0, 0, 0), physicsClientId=self.client)
            p.changeDynamics(
                box.body, -1, activationState=p.ACTIVATION_STATE_WAKE_UP, physicsClientId=self.client
            )
            box.frozen = False

    # -- stepping and reading ------------------------------------------------------------------------
    def step(self, n: int = 1) -> None:
        for _ in range(n):
            p.stepSimulation(physicsClientId=self.client)

    def pose_cm(self, box: WorldBox) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """Centre (cm) and quaternion (x, y, z, w) of one box."""
        pos, orn = p.getBasePositionAndOrientation(box.body, physicsClientId=self.client)
        return (pos[0] / CM, pos[1] / CM, pos[2] / CM), (orn[0], orn[1], orn[2], orn[3])

    def poses_cm(self, boxes: list[WorldBox] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centres (N, 3) cm, quaternions (N, 4) and half extents (N, 3) cm of ``boxes`` (default: all)."""
        boxes = self.boxes if boxes is None else boxes
        centers = np.zeros((len(boxes), 3))
        quats = np.zeros((len(boxes), 4))
        halves = np.zeros((len(boxes), 3))
        cid = self.client
        for i, box in enumerate(boxes):
            pos, orn = p.getBasePositionAndOrientation(box.body, physicsClientId=cid)
            centers[i] = pos
            quats[i] = orn
            halves[i] = box.half_extents_cm
        return centers / CM, quats, halves

    def speeds(self, boxes: list[WorldBox]) -> tuple[float, float]:
        """Largest linear (m/s) and angular (rad/s) speed among ``boxes``."""
        v_max = w_max = 0.0
        cid = self.client
        for box in boxes:
            (vx, vy, vz), (wx, wy, wz) = p.getBaseVelocity(box.body, physicsClientId=cid)
            v = vx * vx + vy * vy + vz * vz
            w = wx * wx + wy * wy + wz * wz
            v_max = v if v > v_max else v_max
            w_max = w if w > w_max else w_max
        return math.sqrt(v_max), math.sqrt(w_max)
