"""PCT's tree nodes on hand-built scenes (worked out by hand), and the policy with the authors' weights."""

import dataclasses

import numpy as np
import pytest

from robobpp.core import Placement, check_action
from robobpp.episode import NO_FEASIBLE_PLACEMENT, Episode, run_episode
from robobpp.policies import load_policy
from robobpp.policies.pct.leaves import SpaceTracker, build_nodes
from tests.conftest import make_spec
from tests.policies.scenes import scene

CORNER_BOX = (0, 0, 4, 3, 2)  # x, y, length, width, height at the container's origin corner


def spaces_of(obs):
    tracker = SpaceTracker(obs.container.length, obs.container.width, obs.container.height)
    return tracker, tracker.sync(obs.placed)


def test_a_box_in_the_corner_leaves_three_maximal_spaces():
    obs = scene((10, 10, 10), [CORNER_BOX], (2, 2, 2))
    _, spaces = spaces_of(obs)
    # beside it along x, beside it along y, above it; nothing below (the reference cuts no slab under a box)
    assert {tuple(s) for s in spaces.tolist()} == {
        (4, 0, 0, 10, 10, 10),
        (0, 3, 0, 10, 10, 10),
        (0, 0, 2, 10, 10, 10),
    }


def test_leaves_are_the_feasible_corners_of_the_spaces_with_reference_features():
    obs = scene((10, 10, 10), [CORNER_BOX], (2, 2, 2))
    _, spaces = spaces_of(obs)
    nodes = build_nodes(obs, spaces, np.random.default_rng(0))
    corners = {(4, 0), (8, 0), (4, 8), (8, 8), (0, 3), (8, 3), (0, 8), (0, 0)}
    assert {(x, y) for x, y, _ in nodes.actions} == corners  # a 2×2 box: one orientation
    valid = nodes.leaves[nodes.leaf_valid]
    assert len(valid) == 11  # (8, 0), (0, 8), (8, 8) come from a floor space and from the space above the box
    on_top = valid[(valid[:, 0] == 0) & (valid[:, 1] == 0)]
    np.testing.assert_array_equal(on_top, [[0, 0, 2, 2, 2, 10, 0, 0]])  # [x0, y0, z_space, x1, y1, H, 0, 0]
    assert nodes.internal_valid.sum() == 1 and nodes.internal[0].tolist() == [0, 0, 0, 4, 3, 2]
    assert nodes.next_item.tolist() == [1, 0, 0, 2, 2, 2]


def test_the_first_internal_node_is_valid_before_any_box():
    obs = scene((10, 10, 10), [], (4, 2, 3))
    nodes = build_nodes(obs, spaces_of(obs)[1], np.random.default_rng(0))
    assert nodes.internal_valid.tolist() == [True] + [False] * 79 and not nodes.internal.any()
    # the four corners of the empty container, in both orientations of a 4×2 box
    assert set(nodes.actions) == {
        (x, y, o) for o, (sx, sy) in enumerate(((4, 2), (2, 4))) for x in (0, 10 - sx) for y in (0, 10 - sy)
    }
    assert nodes.next_item.tolist() == [1, 0, 0, 2, 3, 4]  # sides ascending


def test_leaves_follow_the_support_rule_in_the_physical_settings():
    # a 4 × 6 box on the 4 × 3 corner box at (0, 0): the contact [0, 4] × [0, 3] shrinks to [0.2, 3.8] × [0.15, 2.85]
    math_obs = scene((10, 10, 10), [CORNER_BOX], (4, 6, 1))
    math_nodes = build_nodes(math_obs, spaces_of(math_obs)[1], np.random.default_rng(0))
    assert (0, 0, 0) in math_nodes.actions  # Math Pack: no support rule, as in the reference's Math Pack
    settled = tuple(dataclasses.replace(p, quaternion=(0.0, 0.0, 0.0, 1.0)) for p in math_obs.placed)
    obs = dataclasses.replace(math_obs, placed=settled)  # observed after physics: the rule applies
    nodes = build_nodes(obs, spaces_of(obs)[1], np.random.default_rng(0))
    assert (0, 0, 0) not in nodes.actions  # 4 along x, 6 along y: centre (2, 3) is off the polygon
    assert (0, 0, 1) in nodes.actions  # turned, 6 along x: centre (3, 2) is on it
    assert {(6, 0, 0), (0, 4, 0), (6, 4, 0)} <= set(nodes.actions)  # on the floor: always supported


def test_tracker_rebuilds_when_a_placed_box_moved():
    obs = scene((10, 10, 10), [CORNER_BOX, (4, 0, 2, 2, 2)], (1, 1, 1))
    tracker, spaces = spaces_of(obs)
    moved = (obs.placed[0], Placement(5, 0, 0, 2, 2, 2, 0, 1))  # physics pushed the second box 1 cm along x
    rebuilt = tracker.sync(moved)
    fresh = SpaceTracker(10, 10, 10).sync(moved)
    assert {tuple(s) for s in rebuilt.tolist()} == {tuple(s) for s in fresh.tolist()}
    assert {tuple(s) for s in rebuilt.tolist()} != {tuple(s) for s in spaces.tolist()}


@pytest.mark.network
def test_pct_packs_real_groups_validly_and_deterministically(real_data):
    from robobpp.datasets import episode_specs

    spec = episode_specs("repetitive", split="train", groups=1, seed=0)[0]
    policy = load_policy("pct")
    episode = Episode(spec, "math")
    policy.reset(episode.info)
    while not episode.done:
        obs = episode.observe()
        action = policy.act(obs)
        if action is not None:
            assert check_action(action.x, action.y, action.orientation, obs.box, obs.container) is None
        episode.step(action, 0.0)
    first = episode.result("pct")
    assert first.boxes_placed >= 40
    again = run_episode(spec, load_policy("pct"), "math")
    assert [s.action for s in again.steps] == [s.action for s in first.steps]


@pytest.mark.network
def test_pct_says_no_feasible_placement(real_data):
    spec = make_spec([(5, 5, 5), (20, 20, 20), (5, 5, 5)], container=(10, 10, 10))
    result = run_episode(spec, load_policy("pct"), "math")
    assert result.termination == NO_FEASIBLE_PLACEMENT and result.boxes_placed == 1


def test_the_server_queues_pct_with_the_baselines(tmp_path):
    from sqlalchemy import select

    from robobpp.db.models import Submission
    from robobpp.policies import BASELINES
    from robobpp.server.app import create_app
    from robobpp.server.bootstrap import bootstrap
    from tests.server.test_api import make_settings

    app = create_app(make_settings(f"sqlite:///{tmp_path / 'db.sqlite3'}", tmp_path, evaluate_baselines=True))
    bootstrap(app.state.runtime)
    with app.state.runtime.session() as session:
        urls = set(session.execute(select(Submission.policy_url)).scalars())
        names = set(session.execute(select(Submission.name)).scalars())
    assert urls == {f"builtin:{name}" for name in (*BASELINES, "pct")} and "PCT" in names
