"""What the Execution Pack records for the replay: the robot cell and each operation's joint time line."""

from __future__ import annotations

import json
from collections.abc import Iterator

import numpy as np
import pytest

from robobpp.core import Action, Box, ContainerSpec, EpisodeSpec
from robobpp.sim.execution import ExecutionPack
from robobpp.sim.execution.recording import Q_SCALE, TOLERANCE_RAD
from robobpp.sim.robot.facts import JOINTS, TOOL
from robobpp.sim.robot.kinematics import tcp_pose
from robobpp.web.trace import TraceError, viewer_payload

BOXES = [Box(40, 30, 20, 5.0), Box(30, 30, 20, 3.0)]
ACTIONS = [Action(50, 40, 1), Action(0, 0, 0)]


@pytest.fixture(scope="module")
def run() -> Iterator[tuple[ExecutionPack, list, list]]:
    pack = ExecutionPack()
    spec = EpisodeSpec("handmade", "train", 0, tuple(BOXES), ContainerSpec(134, 125, 100), 7.0, 0)
    pack.reset(spec)
    outcomes, trajectories = [], []
    for i, (box, action) in enumerate(zip(BOXES, ACTIONS, strict=True)):
        outcomes.append(pack.apply(box, action, i))
        operation = pack.last_operation
        assert operation is not None
        trajectories.append(operation.trajectory)
    yield pack, outcomes, trajectories
    pack.close()


def _joints(motion: dict, tick: float) -> np.ndarray:
    """Joint angles at ``tick``, interpolated as the replay does."""
    t = np.array(motion["t"], dtype=float)
    q = np.array(motion["q"], dtype=float).reshape(-1, 6) / Q_SCALE
    return np.array([np.interp(tick, t, q[:, j]) for j in range(6)])


def test_the_cell_is_the_simulators_robot(run: tuple) -> None:
    pack, outcomes, _ = run
    cell = outcomes[0].extra["cell"]
    assert "cell" not in outcomes[1].extra  # once per episode
    assert [j[0] for j in cell["joints"]] == [j.axis for j in JOINTS]
    assert np.allclose([j[1:4] for j in cell["joints"]], [j.origin for j in JOINTS])
    assert cell["tool"] == [TOOL.length, TOOL.radius]
    assert np.allclose(cell["base"][:3], pack.layout.base_position) and len(cell["shapes"]) == 8
    assert np.allclose(cell["home"], pack.layout.home, atol=1e-6)
    json.dumps(cell)  # plain JSON


def test_the_time_line_picks_carries_places_and_retreats(run: tuple) -> None:
    pack, outcomes, _ = run
    layout = pack.layout
    for box, outcome in zip(BOXES, outcomes, strict=True):
        m = outcome.extra["motion"]
        assert all(type(v) is int for v in m["t"] + m["q"]) and len(m["q"]) == 6 * len(m["t"])
        names = [p[0] for p in m["phases"]]
        assert names == ["pick", "transfer", "retreat"]
        assert all(a[2] == b[1] for a, b in zip(m["phases"], m["phases"][1:], strict=False))
        on, off = m["grip"]
        assert (on, off) == (m["phases"][1][1], m["phases"][1][2])
        # The cycle starts and ends at the waiting pose above the conveyor.
        assert m["tick_s"] == pack.config.dt
        assert np.allclose(_joints(m, 0), layout.home, atol=2e-4)
        assert np.allclose(_joints(m, m["t"][-1]), layout.home, atol=2e-4)
        # Suction on at the box's top face on the conveyor, off at the release pose over the target.
        world = lambda q: layout.to_world(tcp_pose(q)[0]) * 100  # noqa: E731
        pick_centre = layout.pick_box_pose(box)[0] * 100
        assert np.allclose(world(_joints(m, on)), pick_centre + [0, 0, box.height / 2], atol=0.05)
        p = outcome.placement
        release = [p.x + p.length / 2, p.y + p.width / 2, box.height + pack.config.release_gap_cm]
        assert np.allclose(world(_joints(m, off))[:2], release[:2], atol=0.5)
        assert abs(world(_joints(m, off))[2] - (p.z + release[2])) < 0.5
        # The carried box hangs below the cup: centre half its height along the tool axis.
        assert np.allclose(m["carry"][:3], [box.height / 200, 0, 0], atol=1e-4)


def test_the_transfer_follows_the_simulated_trajectory(run: tuple) -> None:
    pack, outcomes, trajectories = run
    for outcome, trajectory in zip(outcomes, trajectories, strict=True):
        m = outcome.extra["motion"]
        dt = pack.config.dt
        ticks = np.cumsum(trajectory.sample_counts(dt)) + m["grip"][0]  # where the world drove each waypoint
        recorded = np.stack([_joints(m, t) for t in ticks])
        # Simplified and quantised, never further from the driven waypoints than the tolerance allows.
        error = np.abs(recorded - trajectory.waypoints).max()
        assert error <= TOLERANCE_RAD + 1 / Q_SCALE
        assert len(m["t"]) < len(trajectory.waypoints) + 80  # compact: not every tick


def test_the_replay_reader_takes_and_checks_the_robot(run: tuple) -> None:
    _, outcomes, _ = run
    steps = [
        {
            "step": i,
            "box": {"length": b.length, "width": b.width, "height": b.height},
            "extra": o.extra,
            "placement": {
                "x": o.placement.x,
                "y": o.placement.y,
                "z": o.placement.z,
                "length": o.placement.length,
                "width": o.placement.width,
                "height": o.placement.height,
                "index": i,
            },
        }
        for i, (b, o) in enumerate(zip(BOXES, outcomes, strict=True))
    ]
    episode = json.loads(
        json.dumps({"container": {"length": 134, "width": 125, "height": 100}, "steps": steps})
    )
    payload = viewer_payload(episode)
    assert payload["cell"]["joints"][0][0] == "z" and payload["steps"][1]["motion"]["grip"]
    bad = json.loads(json.dumps(episode))
    bad["steps"][0]["extra"]["motion"]["q"].pop()
    with pytest.raises(TraceError, match=r"motion\.q holds"):
        viewer_payload(bad)
    bad = json.loads(json.dumps(episode))
    bad["steps"][0]["extra"]["cell"]["joints"][2][0] = "w"
    with pytest.raises(TraceError, match=r"joints\[2\]"):
        viewer_payload(bad)
    bad = json.loads(json.dumps(episode))
    bad["steps"][1]["extra"]["motion"]["phases"][0][0] = "dance"
    with pytest.raises(TraceError, match="phases"):
        viewer_payload(bad)


def test_a_box_the_arm_shoves_is_tracked_during_the_transfer() -> None:
    """A slot behind a 95 cm wall: no path, the unchecked palletiser move drives the carried box into the
    wall, which the track shows moving before the release, on the arm's own time line. (By default such a place
    plan ends the episode, as in the reference; here the robot goes on, unchecked.)"""
    boxes = [Box(134, 50, 95, 30.0), Box(20, 15, 10, 1.0)]
    pack = ExecutionPack(end_on_failed_place=False)
    try:
        pack.reset(EpisodeSpec("handmade", "train", 0, tuple(boxes), ContainerSpec(134, 125, 100), 7.0, 0))
        pack.apply(boxes[0], Action(0, 75, 0), 0)
        outcome = pack.apply(boxes[1], Action(57, 58, 0), 1)
    finally:
        pack.close()
    assert outcome.dangerous
    motion, track = outcome.extra["motion"], outcome.extra["track"]
    assert isinstance(motion, dict) and isinstance(track, dict)
    grip_on, grip_off = motion["grip"]
    (wall,) = [row for row in track["boxes"] if row[0] == 0]
    first, samples = wall[1], np.array(wall[2:]).reshape(-1, 7)
    assert grip_on < track["t"][first] < grip_off  # moving while the arm carries the box
    during = [k for k in range(len(samples)) if track["t"][first + k] <= grip_off]
    assert np.abs(samples[during[-1]] - samples[0]).max() > 3  # it had moved before the release
