"""What every baseline must do: load by name, say "no feasible placement" instead of raising, finish
episodes with valid actions, act on a state that physics moved, and give up only when nothing fits."""

from __future__ import annotations

import numpy as np
import pytest

from robobpp.core import Box, ContainerSpec, Observation, Placement, check_action
from robobpp.episode import NO_FEASIBLE_PLACEMENT, Episode, run_episode
from robobpp.policies import BASELINES, load_policy
from tests.conftest import make_spec
from tests.policies.scenes import scene

ALL = list(BASELINES)
#: Policies that search every 1 cm position (the others search EMS corners, SDFPack every second cm).
CELL_POLICIES = {"dbl", "hm", "packe-rules", "random"}


def test_every_paper_baseline_is_registered() -> None:
    expected = {"dbl", "hm", "lsah", "onlinebph", "br", "macs", "sdfpack", "packe-rules", "random"}
    assert set(BASELINES) == expected
    for name in ALL:
        assert load_policy(name).name == name


@pytest.mark.parametrize("name", ALL)
@pytest.mark.parametrize(
    "container, placed, box",
    [
        ((10, 10, 10), [], (11, 11, 1)),  # larger than the floor in both orientations
        ((10, 10, 10), [], (11, 5, 1)),  # too long along x unrotated, too long along y rotated... in 10×10
        ((10, 10, 10), [], (2, 2, 11)),  # taller than the container
        ((10, 10, 10), [(0, 0, 10, 10, 9)], (1, 1, 2)),  # the container is full to 9 of 10 cm
        ((10, 4, 10), [(0, 0, 10, 4, 5)], (3, 3, 6)),  # fits the floor but not the space left above
    ],
)
def test_a_box_that_fits_nowhere_gets_none(name: str, container, placed, box) -> None:
    assert load_policy(name).act(scene(container, placed, box)) is None


@pytest.mark.parametrize("name", ALL)
def test_fits_nowhere_ends_the_episode_with_that_reason(name: str) -> None:
    spec = make_spec([(5, 5, 5), (20, 20, 20), (5, 5, 5)], container=(10, 10, 10))
    result = run_episode(spec, load_policy(name), "math")
    assert result.termination == NO_FEASIBLE_PLACEMENT
    assert result.boxes_placed == 1


@pytest.mark.parametrize("name", ALL)
def test_completes_an_episode_with_valid_actions_and_gives_up_only_when_dbl_does(
    name: str, random_spec
) -> None:
    """Math Pack, 80 random boxes in the Repetitive container. DBL searches every cell, so when a policy that
    also searches every cell says nothing fits, DBL must agree. The EMS policies try only the corners of the
    spaces and SDFPack every second centimetre, as in the reference, and may give up earlier. Every action
    taken is valid and supported (Math Pack would end the episode with ``unsupported`` otherwise)."""
    policy = load_policy(name)
    episode = Episode(random_spec, "math")
    policy.reset(episode.info)
    while not episode.done:
        obs = episode.observe()
        action = policy.act(obs)
        if action is None:
            if name in CELL_POLICIES:
                assert load_policy("dbl").act(obs) is None, f"{name} gave up but DBL found a place"
        else:
            assert isinstance(action.x, float) and float(action.x).is_integer()
            assert check_action(action.x, action.y, action.orientation, obs.box, obs.container) is None
        record = episode.step(action, 0.0)
        assert record.termination in (None, NO_FEASIBLE_PLACEMENT)
    result = episode.result(name)
    assert result.termination in ("completed", NO_FEASIBLE_PLACEMENT)
    assert result.boxes_placed >= 10


@pytest.mark.parametrize("name", ALL)
def test_policies_are_deterministic(name: str, random_spec) -> None:
    first = run_episode(random_spec, load_policy(name), "math")
    second = run_episode(random_spec, load_policy(name), "math")
    assert [s.action for s in first.steps] == [s.action for s in second.steps]


@pytest.mark.parametrize("name", ALL)
def test_acts_on_a_state_physics_moved(name: str) -> None:
    """Closed loop: the boxes are not where the policy put them (fractional, settled lower). The policy
    reads the observed heightmap, so its action is valid for the state as it is."""
    policy = load_policy(name)
    container = ContainerSpec(20, 20, 20)
    first = scene((20, 20, 20), [(0, 0, 6, 6, 6)], (6, 6, 6))
    assert policy.act(first) is not None
    # physics: the box slid to (0.4, 0.3) and something else landed, tilted, at a fractional height
    moved = (
        Placement(0.4, 0.3, 0.0, 6, 6, 6, 0, 0, (0.0, 0.0, 0.0, 1.0)),
        Placement(7.2, 0.0, 0.0, 5, 8, 4.6, 0, 1, (0.01, 0.0, 0.0, 0.99995)),
    )
    from robobpp.core import ContainerState

    state = ContainerState.from_placements(container, moved)
    hm = state.heightmap.view()
    hm.flags.writeable = False
    obs = Observation("scene", 2, container, moved, hm, Box(6, 6, 6))
    action = policy.act(obs)
    assert action is not None
    assert check_action(action.x, action.y, action.orientation, obs.box, container) is None
    z = state.drop(obs.box, action.x, action.y, action.orientation, 2).z
    assert z + 6 <= 20


def test_ems_policies_rebuild_when_the_heightmap_drops() -> None:
    policy = load_policy("onlinebph")
    obs = scene((10, 10, 10), [(0, 0, 10, 10, 8)], (10, 10, 2))
    first, second = policy.act(obs), policy.act(obs)
    assert first is not None and second is not None
    assert (first.x, second.y) == (0.0, 0.0)
    lower = scene((10, 10, 10), [(0, 0, 10, 10, 5)], (10, 10, 4))  # same policy; the load settled to 5 cm
    assert policy.act(lower) is not None  # 5 + 4 ≤ 10; a stale EMS set (floor 8) would say no
    assert policy._tracker.rebuilds == 2  # type: ignore[attr-defined]


def test_random_sizes_never_raise() -> None:
    rng = np.random.default_rng(11)
    for name in ALL:
        policy = load_policy(name)
        for _ in range(20):
            placed = [(0, 0, float(rng.integers(1, 9)), float(rng.integers(1, 9)), float(rng.integers(1, 9)))]
            length, width, height = (float(v) for v in rng.uniform(0.5, 12, size=3))
            box = (length, width, height)
            action = policy.act(scene((9, 8, 10), placed, box))
            if action is not None:
                assert (
                    check_action(action.x, action.y, action.orientation, Box(*box), ContainerSpec(9, 8, 10))
                    is None
                )
