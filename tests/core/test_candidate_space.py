"""The Gym env's candidate action space (``actions="candidates"``): at most K leaf placements with features."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import robobpp  # noqa: F401 - registers robobpp/Pack-v0
from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.env import PackEnv
from robobpp.episode import run_episode
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidate_space import FEATURES, Candidates, CandidateSpace
from tests.conftest import make_spec

COLUMN = {name: i for i, name in enumerate(FEATURES)}


@pytest.fixture
def specs():
    rng = np.random.default_rng(5)
    return [
        make_spec(
            [(float(a), float(b), float(c)) for a, b, c in rng.integers(5, 25, (30, 3))],
            (60, 50, 40),
            group=g,
        )
        for g in range(3)
    ]


def _pack(env: gym.Env) -> PackEnv:
    """The PackEnv under the wrappers of ``gym.make``."""
    pack = env.unwrapped
    assert isinstance(pack, PackEnv)
    return pack


def _candidates(env: gym.Env) -> Candidates:
    """The candidate list of the box to place now."""
    candidates = _pack(env)._candidates
    assert candidates is not None
    return candidates


def test_check_env_passes_and_the_space_is_k_indices(specs):
    env = gym.make("robobpp/Pack-v0", specs=specs, actions="candidates", candidates=20)
    check_env(env.unwrapped)
    assert env.action_space == gym.spaces.Discrete(20)
    obs, info = env.reset(seed=0)
    assert obs["candidates"].shape == (20, len(FEATURES)) and info["action_masks"].shape == (20,)


@pytest.mark.parametrize("setting", ["math", "physics", "execution"])
def test_every_candidate_is_a_feasible_placement_and_padding_is_zero(specs, setting):
    env = gym.make("robobpp/Pack-v0", specs=specs[:1], setting=setting, actions="candidates", candidates=30)
    obs, info = env.reset(seed=0)
    rng = np.random.default_rng(0)
    seen, terminated = 0, False
    while not terminated:
        mask = info["action_masks"]
        assert mask.any()  # an episode with no candidate has ended
        cands = _candidates(env)
        grid = _pack(env).action_mask()  # the env's own feasibility: what a grid action may do
        for k in np.flatnonzero(mask):
            assert grid[tuple(cands.placements[k])], (k, cands.placements[k])
        features = obs["candidates"]
        assert np.array_equal(features[:, COLUMN["valid"]] == 1, mask)
        assert not features[~mask].any()  # padding rows are zeros
        assert features.min() >= 0 and features.max() <= 1
        seen += int(mask.sum())
        obs, reward, terminated, _, info = env.step(int(rng.choice(np.flatnonzero(mask))))
        if not terminated:
            assert info["placed"] and float(reward) > 0
        episode = _pack(env)._episode
        assert episode is not None
        if setting == "execution" and episode.index >= 8:
            return  # the robot's motion planning costs about 0.15 s a box: a few boxes show the rule holds
    assert seen > 30 and info["termination"] in ("completed", "no_feasible_placement")


def test_features_describe_the_placement():
    # a 4 x 10 x 5 block at the back of a 20 x 10 x 20 container, then a 10 x 10 x 2 slab: in the corner x = 0 it
    # rests on the block at z = 5 over 40 of its 100 cells (3 cm of empty height under it on average); at x = 4
    # it lies on the floor, fully supported, nothing wasted
    env = gym.make(
        "robobpp/Pack-v0", specs=[make_spec([(4, 10, 5), (10, 10, 2)], (20, 10, 20))], actions="candidates"
    )
    obs, info = env.reset(seed=0)
    first = np.flatnonzero(info["action_masks"])
    at_origin = [k for k in first if tuple(_candidates(env).placements[k]) == (0, 0, 0)]
    obs, _, _, _, info = env.step(at_origin[0])
    cands = _candidates(env)
    rows = {tuple(cands.placements[k]): obs["candidates"][k] for k in np.flatnonzero(info["action_masks"])}
    on_block, on_floor = rows.get((0, 0, 0)), rows.get((4, 0, 0))
    assert on_block is not None and on_floor is not None, sorted(rows)
    f = COLUMN
    assert on_block[f["z"]] == pytest.approx(5 / 20) and on_block[f["top"]] == pytest.approx(7 / 20)
    assert on_block[f["support"]] == pytest.approx(0.4) and on_block[f["gap"]] == pytest.approx(3 / 20)
    assert on_block[f["x1"]] == pytest.approx(10 / 20) and on_block[f["y1"]] == pytest.approx(1.0)
    assert on_floor[f["z"]] == 0 and on_floor[f["support"]] == 1 and on_floor[f["gap"]] == 0
    assert on_floor[f["x0"]] == pytest.approx(4 / 20)


class FirstCandidate(BasePolicy):
    """Candidate 0 of the list, built as a served policy would build it."""

    name = "first-candidate"

    def __init__(self) -> None:
        self.space = CandidateSpace(10)

    def reset(self, info: EpisodeInfo) -> None:
        self.space.reset(info.container, info.episode_id)

    def act(self, obs: Observation) -> Action | None:
        return self.space(obs).action(0)


def test_the_env_and_a_policy_see_the_same_list_for_the_same_episode(specs):
    """Seeded by the episode: the agent trained in the env meets the same candidates when it is evaluated."""
    env = gym.make("robobpp/Pack-v0", specs=specs, actions="candidates", candidates=10)
    env.reset(seed=0, options={"group": 2})
    placed, terminated = [], False
    while not terminated:
        placed.append(tuple(_candidates(env).placements[0]))
        _, _, terminated, _, info = env.step(0)
    records: list = []
    result = run_episode(specs[2], FirstCandidate(), "math", on_step=records.append)
    actions = [
        (int(r.action["x"]), int(r.action["y"]), int(r.action["orientation"])) for r in records if r.action
    ]
    assert actions == placed[: len(actions)] and len(actions) >= len(placed) - 1
    assert result.metrics["space_utilization"] == pytest.approx(info["metrics"]["space_utilization"])


def test_a_masked_slot_ends_the_episode_and_an_index_outside_is_refused(specs):
    env = gym.make("robobpp/Pack-v0", specs=specs[:1], actions="candidates", candidates=500)
    _, info = env.reset(seed=0)
    with pytest.raises(ValueError, match=r"candidate index in \[0, 500\)"):
        env.step(500)
    empty = int(np.flatnonzero(~info["action_masks"])[0])
    _, reward, terminated, _, info = env.step(empty)
    assert terminated and reward == 0 and info["termination"] == "policy_error"
    assert "names no candidate" in info["termination_detail"]


@pytest.mark.network
def test_the_features_carry_what_a_good_choice_needs(real_data):
    """Lowest resting height first (then nearest the corner), read off the features alone, packs Repetitive
    train groups far better than a random candidate: the list and its features are enough to learn from."""
    env = gym.make("robobpp/Pack-v0", dataset="repetitive", actions="candidates")
    rng = np.random.default_rng(0)
    totals = {"greedy": 0.0, "random": 0.0}
    groups = 4
    for rule in totals:
        for g in range(groups):
            obs, info = env.reset(seed=g, options={"group": g})
            terminated = False
            while not terminated:
                valid = np.flatnonzero(info["action_masks"])
                f = obs["candidates"][valid]
                order = np.lexsort((f[:, COLUMN["x0"]] + f[:, COLUMN["y0"]], f[:, COLUMN["z"]]))
                k = valid[order[0]] if rule == "greedy" else rng.choice(valid)
                obs, _, terminated, _, info = env.step(int(k))
            totals[rule] += info["metrics"]["space_utilization"]
    assert totals["greedy"] > totals["random"] + 0.1 * groups, totals
