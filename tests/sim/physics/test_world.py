"""The PyBullet world: documented defaults, friction as specified, isolated clients, optional walls."""

from __future__ import annotations

import math

import pybullet as p
import pytest

from robobpp.core import ContainerSpec
from robobpp.sim.physics import PhysicsConfig, PhysicsWorld

PALLET = ContainerSpec(134, 125, 100)


def test_defaults_are_the_benchmarks() -> None:
    cfg = PhysicsConfig()
    assert cfg.dt == pytest.approx(1 / 240)
    assert cfg.gravity == pytest.approx(9.81)
    assert cfg.lateral_friction == pytest.approx(1.0)  # the reference implementation's
    assert cfg.box_mass_kg == pytest.approx(0.5)
    assert cfg.restitution == 0.0
    assert cfg.walls is False
    assert cfg.stability_steps == 200
    with PhysicsWorld() as world:
        params = p.getPhysicsEngineParameters(physicsClientId=world.client)
        assert params["fixedTimeStep"] == pytest.approx(1 / 240)
        assert params["gravityAccelerationZ"] == pytest.approx(-9.81)


@pytest.mark.parametrize(
    "bad",
    [
        dict(dt=0.0),
        dict(gravity=-1.0),
        dict(lateral_friction=-0.1),
        dict(restitution=2.0),
        dict(release_gap_cm=float("nan")),
        dict(mode="turbo"),
        dict(max_steps=0),
        dict(box_mass_kg=0.0),
        dict(clear_gap_cm=-0.1),
        dict(collision_shape="sphere"),
        dict(release="drop"),
        dict(lower_step_cm=0.0),
        dict(lower_from_cm=-1.0),
    ],
)
def test_bad_config_is_refused(bad: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        PhysicsConfig(**bad)  # type: ignore[arg-type]


def _landing(config: PhysicsConfig, beside: bool = False) -> tuple[int, float, float, float]:
    """A 40 × 30 × 20 cm box put 1.7 cm above the deck and lowered until it touches (beside a 60 cm tall box
    whose side it touches, if ``beside``): (steps, v max, ω max over 200 steps, height of its bottom, cm)."""
    with PhysicsWorld(config) as world:
        world.add_pallet(PALLET)
        moving = []
        if beside:  # a tall box whose side the new one's side touches exactly (a gapless grid)
            wall = world.add_box((10, 40, 30), (20, 40, 60), 0.5)  # x 0-20: the new box's x starts at 20
            world.step(240)
            moving.append(wall)
        box = world.add_box((40, 40, 10 + config.lower_from_cm), (40, 30, 20), 0.5)
        moving.append(box)
        steps = world.lower_until_contact(box, config.lower_from_cm, config.lower_step_cm)
        v_max = w_max = 0.0
        for _ in range(200):
            world.step()
            v, w = world.speeds(moving)
            v_max, w_max = max(v_max, v), max(w_max, w)
        if beside:
            assert world.pose_cm(moving[0])[0][2] == pytest.approx(30, abs=0.1)  # the neighbour stands by
        return steps, v_max, w_max, world.pose_cm(box)[0][2] - 10


def test_a_box_lands_as_the_reference_lands_it() -> None:
    """Lowered 1 mm per step from 1.7 cm up, the mesh box is reported touching 1-2 mm before it does and
    falls that last bit: it lands at 0.1-0.2 m/s (the reference's ≈ 0.12), not still and not from 1.7 cm
    (≈ 0.58 m/s), and rests on its real size (the mesh is shrunk by Bullet's margin)."""
    steps, v, _, bottom = _landing(PhysicsConfig())
    assert 14 <= steps <= 17
    assert 0.1 <= v <= 0.2
    assert bottom == pytest.approx(0.0, abs=0.05)
    # A box primitive lowered the same way is reported touching only when it does: it lands still.
    _, v_box, _, _ = _landing(PhysicsConfig(collision_shape="box"))
    assert v_box < 0.03


def test_a_neighbours_side_does_not_end_the_lowering() -> None:
    """On a gapless grid the neighbour's side is within Bullet's reporting distance from the first step; only
    a touch from below ends the lowering, so the box still lands from 1-2 mm, not from 1.7 cm."""
    steps, v, _, bottom = _landing(PhysicsConfig(), beside=True)
    assert steps >= 14 and v <= 0.2
    assert bottom == pytest.approx(0.0, abs=0.05)


def test_box_comes_to_rest_on_the_pallet() -> None:
    with PhysicsWorld() as world:
        world.add_pallet(PALLET)
        box = world.add_box((20, 20, 8), (30, 20, 10), 5.0)
        world.step(240)
        (x, y, z), quat = world.pose_cm(box)
        assert (x, y) == pytest.approx((20, 20), abs=0.05)
        assert z == pytest.approx(5.0, abs=0.05)  # fell the 3 cm and sits on the deck
        assert world.speeds([box])[0] < 1e-3


@pytest.mark.parametrize(
    ("friction", "slope", "slides"),
    [(1.0, 0.9, False), (1.0, 1.1, True), (0.5, 0.45, False), (0.5, 0.55, True)],
)
def test_pair_friction_is_as_configured(friction: float, slope: float, slides: bool) -> None:
    """Tilting gravity by atan(slope): a box sticks below μ and slides above it (Bullet multiplies)."""
    with PhysicsWorld(PhysicsConfig(lateral_friction=friction)) as world:
        world.add_pallet(PALLET)
        box = world.add_box((60, 60, 5), (30, 20, 10), 5.0)
        theta = math.atan(slope)
        p.setGravity(9.81 * math.sin(theta), 0, -9.81 * math.cos(theta), physicsClientId=world.client)
        world.step(240)
        moved = world.pose_cm(box)[0][0] - 60
        assert (moved > 5) is slides, moved


def test_worlds_do_not_share_state() -> None:
    a, b = PhysicsWorld(), PhysicsWorld()
    try:
        assert a.client != b.client
        a.add_pallet(PALLET)
        b.add_pallet(PALLET)
        box_a = a.add_box((20, 20, 50), (10, 10, 10), 1.0)
        box_b = b.add_box((20, 20, 50), (10, 10, 10), 1.0)
        a.step(60)
        assert a.pose_cm(box_a)[0][2] < 45  # falling in a
        assert b.pose_cm(box_b)[0][2] == pytest.approx(50)  # untouched in b
        a.close()
        b.step(60)
        assert b.pose_cm(box_b)[0][2] < 45
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("walls", [False, True])
def test_walls_are_optional(walls: bool) -> None:
    with PhysicsWorld(PhysicsConfig(walls=walls)) as world:
        world.add_pallet(ContainerSpec(60, 60, 50))
        box = world.add_box((50, 30, 5.01), (10, 10, 10), 1.0)
        p.resetBaseVelocity(box.body, (3.0, 0, 0), (0, 0, 0), physicsClientId=world.client)
        world.step(240)
        x = world.pose_cm(box)[0][0]
        assert (x <= 55.5) is walls, x


def test_frozen_box_holds_still_and_wakes_up() -> None:
    with PhysicsWorld() as world:
        world.add_pallet(PALLET)
        box = world.add_box((20, 20, 40), (10, 10, 10), 1.0)
        world.freeze(box)
        world.step(60)
        assert world.pose_cm(box)[0][2] == pytest.approx(40)
        world.unfreeze(box)
        world.step(120)
        assert world.pose_cm(box)[0][2] == pytest.approx(5, abs=0.05)


def _resting_drift_um(config: PhysicsConfig) -> float:
    """The largest horizontal drift (µm) of a 24-box bonded stack over 8 s after it has settled for 2 s."""
    with PhysicsWorld(config) as world:
        world.add_pallet(PALLET)
        for layer in range(4):
            for i in range(3):
                for j in range(2):
                    centre = (20 + 5 * (layer % 2) + 30.0 * i, 20 + 20.0 * j, 5 + 10.0 * layer)
                    world.add_box(centre, (29.9, 19.9, 10), 0.5)
        world.step(480)
        before = world.poses_cm()[0]
        world.step(1920)
        after = world.poses_cm()[0]
    return float(abs(after[:, :2] - before[:, :2]).max() * 1e4)


def test_a_resting_stack_does_not_creep() -> None:
    """Friction anchors (physics version 3): a well-supported stack with friction 1 at rest stays put. Without
    them the velocity-level friction lets it creep steadily (about 0.1 mm/s here), an artefact of the time
    step (docs/validation/physics.md, "Creep")."""
    assert _resting_drift_um(PhysicsConfig()) < 10
    assert _resting_drift_um(PhysicsConfig(friction_anchor=False)) > 100


#: Long Board DBL train group 0's first cantilever as its Math plan stacks it (x, y, z, length, width, height, cm):
#: a 218 cm board on a 133 cm one, 85 cm of it overhanging, six boxes on it, the pile's centre of mass 6 cm inside
#: the support's end.
LONG_BOARD_CANTILEVER = (
    (0, 0, 0, 133, 60, 9.5),
    (0, 0, 9.5, 218, 64, 6.5),
    (0, 0, 16, 150, 62, 8.5),
    (150, 0, 16, 76, 64, 12),
    (0, 0, 24.5, 73, 63, 12.5),
    (73, 0, 24.5, 73, 63, 12.5),
    (146, 0, 28, 72, 60, 5.5),
    (146, 0, 33.5, 87, 63, 12.5),
)


def _cantilever_drift_cm(config: PhysicsConfig) -> float:
    """The largest horizontal drift (cm) of the Long Board cantilever over the reference implementation's
    simulation steps for one placement in its Physics Pack (3,815), after 1 s of settling."""
    with PhysicsWorld(config) as world:
        world.add_pallet(ContainerSpec(250, 120, 100))
        for x, y, z, length, width, height in LONG_BOARD_CANTILEVER:
            world.add_box(
                (x + length / 2, y + width / 2, z + height / 2 + 0.001), (length, width, height), 0.5
            )
        world.step(240)
        before = world.poses_cm()[0]
        world.step(3815)
        after = world.poses_cm()[0]
    return float(abs(after[:, :2] - before[:, :2]).max())


def test_a_long_board_cantilever_stands_and_creeps_only_without_anchors() -> None:
    """The pile stands (friction 1, its centre of mass over its support): with friction anchors nothing moves.
    Without them, as in the reference implementation, it creeps about 1 cm per placement's worth of steps; the
    reference's Long Board piles end by its 7 cm collapse rule that way (docs/validation/execution.md, "Why the reference's
    Long Board piles collapse")."""
    assert _cantilever_drift_cm(PhysicsConfig()) < 0.01
    assert _cantilever_drift_cm(PhysicsConfig(friction_anchor=False)) > 0.5
