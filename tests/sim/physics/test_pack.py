"""Physics Pack: physics visibly happens — stacks stay, overhangs fall, narrow supports tip."""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pybullet as p
import pytest

from robobpp.core import Action, Box
from robobpp.sim import make_setting
from robobpp.sim.physics import PhysicsPack, PhysicsWorld, detect_collapse, stability_reward
from tests.sim.physics._physics_specs import spec_of


def _pack(boxes: list[Box], **kw: Any) -> PhysicsPack:
    pack = PhysicsPack()
    pack.reset(spec_of(boxes, **kw))
    return pack


def test_make_setting_builds_it() -> None:
    setting = make_setting("physics", mode="full")
    assert isinstance(setting, PhysicsPack) and setting.name == "physics" and setting.config.mode == "full"


def test_unknown_option_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown physics option"):
        make_setting("physics", gravitee=9.81)
    with pytest.raises(ValueError):
        PhysicsPack(dt=-1.0)


def test_well_supported_stack_stays() -> None:
    box = Box(40, 30, 20, 8.0)
    pack = _pack([box] * 4)
    for i in range(4):
        out = pack.apply(box, Action(10, 10, 0), i)
        assert out.termination is None and not out.collapsed
        assert out.placement is not None and out.placement.z == pytest.approx(20 * i, abs=0.1)
        assert 0.3 < (out.static_stability or 0) <= 1
    final = pack.final_boxes()
    assert all(f.in_place for f in final)
    offsets = [
        sum((a - b) ** 2 for a, b in zip(f.planned.center, f.actual.center, strict=True)) ** 0.5
        for f in final
    ]
    assert max(offsets) < 0.2  # cm: a well-supported stack stays where it was put
    state = pack.state()
    assert state.heightmap[10:50, 10:40].min() == pytest.approx(80, abs=0.1)
    assert state.heightmap[0:9, :].max() == 0
    assert all(p.quaternion is not None for p in state.placements)
    pack.close()


def test_box_over_a_gap_falls_and_collapse_is_detected() -> None:
    """Four fifths of the footprint over nothing: the box tips off its 40 cm post onto the deck."""
    support, plank = Box(20, 20, 40, 5.0), Box(40, 20, 10, 5.0)
    pack = _pack([support, plank])
    assert pack.apply(support, Action(30, 30, 0), 0).termination is None
    out = pack.apply(plank, Action(42, 30, 0), 1)
    assert out.collapsed
    assert out.termination is not None and out.termination.reason == "collapse"
    # Which box moved, how far, against which threshold, after which placement, numbered as "N / M boxes
    # placed" counts (it read "box 1 moved … (threshold 7 cm); 1 box(es) beyond it after placing box 1").
    # (Falling, the plank may knock the post over too: the farthest mover is named first, then the count.)
    assert re.fullmatch(
        r"after placing box #1 \(the 2nd\), box #[01] \(the (1st|2nd)\) moved \d+\.\d cm along x or y "
        r"from where it was placed, more than the collapse threshold of 7 cm"
        r"(; 2 boxes in all moved past the threshold or fell)?",
        out.termination.detail,
    ), out.termination.detail
    assert out.placement is not None and out.placement.z < 10  # it ended on the deck, not at 40 cm
    assert out.placement.quaternion is not None
    assert out.static_stability is not None and out.static_stability < 0.3  # it moved fast
    final = pack.final_boxes()
    assert final[1].in_place is False
    pack.close()


def test_threshold_comes_from_the_spec() -> None:
    """The same fall is no collapse when the episode's threshold is larger than the displacement."""
    support, plank = Box(20, 20, 40, 5.0), Box(40, 20, 10, 5.0)
    pack = _pack([support, plank], threshold=100.0)
    pack.apply(support, Action(30, 30, 0), 0)
    out = pack.apply(plank, Action(42, 30, 0), 1)
    assert not out.collapsed and out.termination is None
    assert out.placement is not None and out.placement.z < 10  # it still fell
    assert pack.final_boxes()[1].in_place
    pack.close()


@pytest.mark.parametrize(("offset", "tips"), [(0.0, False), (8.0, True)])
def test_heavy_box_on_narrow_support(offset: float, tips: bool) -> None:
    """A 30 kg slab balanced on a 10 × 10 cm post stays; shifted 8 cm off the post's axis, it tips."""
    post, slab = Box(10, 10, 30, 2.0), Box(40, 40, 8, 30.0)
    pack = _pack([post, slab])
    pack.apply(post, Action(60, 60, 0), 0)
    out = pack.apply(slab, Action(45 + offset, 45, 0), 1)
    assert out.collapsed is tips
    assert out.placement is not None
    assert (out.placement.z < 20) is tips
    pack.close()


def test_too_high_is_refused_before_release() -> None:
    tall = Box(30, 30, 60, 2.0)
    pack = _pack([tall, tall])
    assert pack.apply(tall, Action(0, 0, 0), 0).termination is None
    out = pack.apply(tall, Action(0, 0, 0), 1)
    assert out.placement is None and out.termination is not None and out.termination.reason == "too_high"
    assert len(pack.final_boxes()) == 1
    pack.close()


def test_resting_height_follows_the_physical_pile() -> None:
    """After the plank fell, its actual pose — not its planned one — decides where the next box rests."""
    support, plank, cube = Box(20, 20, 40, 5.0), Box(40, 20, 10, 5.0), Box(10, 10, 10, 1.0)
    pack = _pack([support, plank, cube], threshold=100.0)
    pack.apply(support, Action(30, 30, 0), 0)
    pack.apply(plank, Action(42, 30, 0), 1)
    planned_top = 50.0
    assert pack.resting_height(70, 30, 10, 10) < planned_top - 5
    assert pack.state().heightmap[70:80, 30:40].max() < planned_top - 5
    pack.close()


def test_fall_off_the_pallet_is_collapse() -> None:
    """A box that lands beside the pallet counts as fallen whatever the threshold."""
    from robobpp.core import ContainerSpec

    with PhysicsWorld() as world:
        world.add_pallet(ContainerSpec(100, 100, 100))
        on, off = (
            world.add_box((50, 50, 5), (10, 10, 10), 1.0),
            world.add_box((105, 50, 5), (30, 10, 10), 1.0),
        )
        world.step(480)
        moved = detect_collapse(
            world, [on, off], np.array([(50, 50, 5), (105, 50, 5)]), [0, 1], threshold_cm=1000
        )
        assert [(d.index, d.fell) for d in moved] == [(1, True)]
        assert moved[0].describe(1000) == "box #1 (the 2nd) fell off the pallet"
        assert world.pose_cm(off)[0][2] < 0  # it really lies on the ground below the deck


def test_reset_is_required_and_starts_afresh() -> None:
    pack = PhysicsPack()
    with pytest.raises(RuntimeError):
        pack.state()
    box = Box(20, 20, 20, 1.0)
    pack.reset(spec_of([box]))
    pack.apply(box, Action(0, 0, 0), 0)
    pack.reset(spec_of([box]))
    assert pack.state().placements == [] and pack.final_boxes() == []
    pack.close()


def test_stability_reward() -> None:
    assert stability_reward(0.1, 0.5, [0.01, 0.03]) == pytest.approx(1.0 + 0.005 - 0.02)
    assert stability_reward(0.0, None, []) == 0.0
    with pytest.raises(ValueError):
        stability_reward(float("nan"), 0.5, [])


@pytest.mark.parametrize(("threshold", "collapsed"), [(6.0, False), (4.9, True)])
def test_collapse_is_dx_or_dy_over_the_threshold(threshold: float, collapsed: bool) -> None:
    """The reference implementation's rule: 5 cm along x and 5 cm along y (7.1 cm diagonally) is within a
    6 cm threshold; either component over it is a collapse."""
    from robobpp.core import ContainerSpec

    with PhysicsWorld() as world:
        world.add_pallet(ContainerSpec(100, 100, 100))
        box = world.add_box((50, 50, 5), (10, 10, 10), 1.0)
        moved = detect_collapse(world, [box], np.array([(45, 45, 5)]), [0], threshold_cm=threshold)
        assert bool(moved) is collapsed
        if moved:
            assert moved[0].horizontal_cm == pytest.approx(5.0, abs=0.01)


@pytest.mark.parametrize("noise", [-0.002, 0.0, 0.002])
def test_observation_does_not_flip_on_a_tenth_of_a_millimetre(noise: float) -> None:
    """A 42.5 cm box put at x = 45 ends at 87.5: half of cell 87. Settling noise of a few hundredths of a
    millimetre either way must give the policy the same heightmap (the half-covered cell claimed, as in
    the Math Pack) and the same placements (rounded to 1 mm, so ``floor`` of a corner on the grid holds)."""
    box = Box(42.5, 32.5, 27.0, 9.0)
    pack = _pack([box])
    pack.apply(box, Action(45, 0, 0), 0)
    world = pack.world
    assert world is not None
    (x, y, z), quat = world.pose_cm(pack.boxes[0])
    p.resetBasePositionAndOrientation(
        pack.boxes[0].body, ((x + noise) / 100, y / 100, z / 100), quat, physicsClientId=world.client
    )
    pack._state = None  # the pose was moved by hand
    state = pack.state()
    assert state.heightmap[45:88, 0:33].min() == pytest.approx(27.0)
    assert state.heightmap[88:, :].max() == 0 and state.heightmap[:45, :].max() == 0
    placed = state.placements[0]
    assert (placed.x, placed.y, placed.z) == (45.0, 0.0, 0.0)
    # Outcomes and metrics keep the measured pose (the landing may have moved it by hundredths of a mm).
    assert pack.final_boxes()[0].actual.x == pytest.approx(x + noise - box.length / 2, abs=1e-9)
    pack.close()


def test_a_board_that_tilts_in_place_counts_as_placed() -> None:
    """A 100 cm board over a 40 cm box: it tips about the box's edge until its far end rests on the deck. Its
    centre moves far less than the threshold horizontally, so — as in the reference, whose collapse rule reads
    only |dx| and |dy| of the centre — it is no collapse and counts as in place, tilted and all."""
    import math

    from robobpp.scoring import metrics as M

    base, board = Box(40, 20, 10, 5.0), Box(100, 20, 2, 5.0)
    pack = _pack([base, board])
    assert pack.apply(base, Action(0, 30, 0), 0).termination is None
    out = pack.apply(board, Action(0, 30, 0), 1)
    assert not out.collapsed and out.termination is None
    final = pack.final_boxes()
    assert [f.in_place for f in final] == [True, True]
    planned, actual = final[1].planned, final[1].actual
    assert actual.quaternion is not None
    tilt = math.degrees(2 * math.acos(min(1.0, abs(actual.quaternion[3]))))
    assert 5 < tilt < 15  # it leans: from 10 cm over the box's edge down to the deck, over 60 cm
    assert actual.center[2] < planned.center[2] - 1  # its centre dropped (10 cm from the edge: ≈ 1.7 cm)
    assert max(abs(a - b) for a, b in zip(actual.center[:2], planned.center[:2], strict=True)) < 7
    # a seesaw on the box's edge: the end over the box rose, and the observed heightmap (a tilted box claims its
    # bounds' top) shows it above the planned top of 12 cm
    assert pack.state().heightmap[0:5, 35:45].max() > 12 + 3
    volume = (40 * 20 * 10 + 100 * 20 * 2) / pack.spec.container.volume  # type: ignore[union-attr]
    assert M.space_utilization(final, pack.spec.container) == pytest.approx(volume)  # type: ignore[union-attr]
    pack.close()
