from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import robobpp
import robobpp.env
from robobpp.episode import Episode
from tests.conftest import make_spec


@pytest.fixture
def specs():
    rng = np.random.default_rng(3)
    return [
        make_spec(
            [(float(a), float(b), float(c)) for a, b, c in rng.integers(5, 25, (20, 3))],
            (60, 50, 40),
            group=g,
        )
        for g in range(4)
    ]


def _pack(env: gym.Env) -> robobpp.env.PackEnv:
    """The PackEnv under the wrappers of ``gym.make``."""
    pack = env.unwrapped
    assert isinstance(pack, robobpp.env.PackEnv)
    return pack


def _episode(pack: robobpp.env.PackEnv) -> Episode:
    """The episode under way (after a reset)."""
    assert pack._episode is not None
    return pack._episode


def test_check_env_passes(specs):
    env = gym.make("robobpp/Pack-v0", specs=specs)
    check_env(env.unwrapped)


def test_the_heightmap_is_one_image_channel(specs):
    env = gym.make("robobpp/Pack-v0", specs=specs)
    obs, _ = env.reset(seed=0)
    space = env.observation_space
    assert isinstance(space, gym.spaces.Dict)
    assert space["heightmap"].shape == (1, 60, 50)
    assert obs["heightmap"].shape == (1, 60, 50) and obs["heightmap"].dtype == np.float32
    np.testing.assert_array_equal(obs["heightmap"][0], _episode(_pack(env)).observe().heightmap)


@pytest.mark.parametrize("setting", ["math", "physics"])
def test_every_observation_and_mask_is_the_state_s_at_that_step(specs, setting):
    """The heightmap channel and the action mask the env keeps up to date box after box are, at every step, what
    the state computed afresh gives (Math Pack: caught up from the placed blocks; Physics Pack: a new state each
    step, rebuilt)."""
    env = gym.make("robobpp/Pack-v0", specs=specs, setting=setting)
    pack = _pack(env)
    rng = np.random.default_rng(1)
    steps, episode, enough = 0, 0, 60 if setting == "math" else 12
    while steps < enough:
        obs, info = env.reset(seed=episode)
        episode, done = episode + 1, False
        while not done:
            state = _episode(pack).setting.state()
            expected = robobpp.env.heightmap_channel(state.heightmap, pack.container.height)
            np.testing.assert_array_equal(obs["heightmap"], expected)
            if pack._box is not None:
                fresh = robobpp.env.feasible_mask(_episode(pack).observe())
                np.testing.assert_array_equal(info["action_masks"], fresh.reshape(-1))
            obs, _, done, _, info = env.step(int(rng.choice(np.flatnonzero(info["action_masks"]))))
            steps += 1


def test_stable_baselines3_check_env_takes_the_heightmap_as_an_image(specs):
    """sb3's checker warned "unconventional shape (neither an image, nor a 1D vector)" for a (nx, ny) heightmap;
    a (1, nx, ny) one is a one-channel image to it (it still says float images are not uint8 ones)."""
    pytest.importorskip("stable_baselines3", reason="needs the learn extra: pip install -e '.[learn]'")
    import warnings

    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sb3_check_env(gym.make("robobpp/Pack-v0", specs=specs))
    messages = [str(w.message) for w in caught]
    assert not [m for m in messages if "unconventional shape" in m], messages


def test_returned_arrays_do_not_change_after_they_are_returned(specs):
    """Observations and masks an agent keeps (a rollout buffer) are its own: later steps do not rewrite them,
    and writing to them does not reach the env."""
    env = gym.make("robobpp/Pack-v0", specs=specs, lookahead=2, support_info=True)
    pack = _pack(env)
    obs, info = env.reset(seed=0, options={"group": 0})
    kept = [
        ({k: v.copy() for k, v in obs.items()}, obs),
        ({k: v.copy() for k, v in info.items() if k != "episode_id"}, info),
    ]
    mask = pack.action_mask()
    kept.append(({"mask": mask.copy()}, {"mask": mask}))
    for _ in range(3):
        obs, _, terminated, _, info = env.step(int(np.flatnonzero(pack.action_masks())[0]))
        assert not terminated
        for array in (*obs.values(), info["action_masks"], info["support_mask"]):
            array[...] = 0  # scribbling on what was returned
    assert obs["heightmap"].max() == 0 and pack._mask.any()  # the env's own state is untouched
    for copies, returned in kept:
        for key, value in copies.items():
            np.testing.assert_array_equal(returned[key], value)


def test_masked_actions_fill_the_container(specs):
    env = gym.make("robobpp/Pack-v0", specs=specs, lookahead=2)
    obs, info = env.reset(seed=0, options={"group": 1})
    assert obs["lookahead"].shape == (2, 4) and info["episode_id"].endswith("001")
    total, steps, terminated = 0.0, 0, False
    while not terminated:
        mask = _pack(env).action_mask()
        assert mask.any()  # an episode with nothing feasible has already ended
        x, y, o = np.argwhere(mask)[0]
        obs, reward, terminated, truncated, info = env.step(np.ravel_multi_index((x, y, o), mask.shape))
        assert info["placed"] and float(reward) > 0
        total += float(reward)
        steps += 1
    assert steps > 5 and info["termination"] in ("completed", "no_feasible_placement")
    utilisation = _episode(_pack(env)).result("x").metrics["space_utilization"]
    assert utilisation is not None
    assert total == pytest.approx(float(utilisation))


def test_infeasible_action_terminates_with_reason(specs):
    env = gym.make("robobpp/Pack-v0", specs=specs)
    env.reset(seed=0)
    _, reward, terminated, _, info = env.step(np.ravel_multi_index((59, 49, 0), _pack(env).grid_shape))
    assert terminated and reward == 0.0 and info["termination"] == "out_of_bounds"


def test_unknown_reward_is_refused(specs):
    with pytest.raises(ValueError, match="unknown reward"):
        robobpp.env.PackEnv(specs=specs, reward="bogus")


@pytest.mark.slow
def test_stability_reward_in_physics_setting(specs):
    env = gym.make("robobpp/Pack-v0", specs=specs[:1], setting="physics", reward="stability")
    env.reset(seed=0)
    rewards = []
    for _ in range(3):
        x, y, o = np.argwhere(_pack(env).action_mask())[0]
        _, reward, terminated, _, info = env.step(np.ravel_multi_index((x, y, o), _pack(env).grid_shape))
        rewards.append(reward)
        if terminated:
            break
    volume_ratio = np.prod(specs[0].boxes[0].dims(0)) / specs[0].container.volume
    # 10 × volume ratio + a small stability bonus (≤ 0.01) − a small offset of a resting box
    assert 10 * volume_ratio - 0.01 < rewards[0] <= 10 * volume_ratio + 0.01
    env.close()


def test_malformed_action_says_what_an_action_is(specs):
    env = gym.make("robobpp/Pack-v0", specs=specs).unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match="one index into the flat action space"):
        env.step(np.array([1, 2, 0]))  # an (x, y, orientation) triple where the default space takes an index
    with pytest.warns(UserWarning, match="superset"):
        grid = gym.make("robobpp/Pack-v0", specs=specs, actions="grid").unwrapped
    grid.reset(seed=0)
    with pytest.raises(ValueError, match=r"\(x, y, orientation\)"):
        grid.step(np.int64(17))  # a flat index into the mask


@pytest.mark.network
def test_gym_rollout_example_runs(real_data):
    import os
    import subprocess
    import sys
    from pathlib import Path

    example = Path(__file__).resolve().parents[2] / "examples" / "gym_rollout.py"
    proc = subprocess.run(
        [sys.executable, str(example), "--episodes", "2", "--groups", "2"],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "ROBOBPP_DATA_DIR": str(real_data)},
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 2 and all(
        line.startswith("repetitive-train-") and " boxes, return " in line for line in lines
    )
    assert len({line.split(":")[0] for line in lines}) == 2  # a different group each episode


def test_no_feasible_placement_ends_the_episode():
    specs = [make_spec([(10, 10, 6), (10, 10, 6), (1, 1, 1)], (10, 10, 10))]
    env = gym.make("robobpp/Pack-v0", specs=specs)
    _, info = env.reset(seed=0)
    assert info["action_masks"].any()
    _, reward, terminated, truncated, info = env.step(0)  # (0, 0, orientation 0)
    # the second box (6 cm on 6 cm) exceeds the 10 cm height everywhere: the episode ends with the placement
    assert terminated and not truncated and reward == pytest.approx(0.6)
    assert info["placed"] and info["termination"] == "no_feasible_placement"
    assert not info["action_masks"].any() and not _pack(env).action_masks().any()
    result = _episode(_pack(env)).result("x")
    assert result.termination == "no_feasible_placement" and result.boxes_placed == 1
    # the step that ends the episode carries its figures, as the evaluator computes them
    assert info["boxes_placed"] == 1 and info["termination_detail"] == result.termination_detail
    assert info["metrics"] == result.metrics and info["metrics"]["space_utilization"] == pytest.approx(0.6)


def test_flat_actions_and_masks_follow_the_action_space(specs):
    flat = gym.make("robobpp/Pack-v0", specs=specs)  # the default
    with pytest.warns(UserWarning, match="superset"):
        grid = gym.make("robobpp/Pack-v0", specs=specs, actions="grid")
    check_env(flat.unwrapped)
    _, info = flat.reset(seed=0, options={"group": 2})
    grid.reset(seed=0, options={"group": 2})
    joint = _pack(grid).action_mask()
    assert isinstance(flat.action_space, gym.spaces.Discrete)
    assert flat.action_space.n == joint.size
    np.testing.assert_array_equal(info["action_masks"], joint.reshape(-1))
    np.testing.assert_array_equal(_pack(flat).action_masks(), joint.reshape(-1))
    per_dim = _pack(grid).action_masks()  # MultiDiscrete: one mask per dimension, concatenated
    assert isinstance(grid.action_space, gym.spaces.MultiDiscrete)
    assert per_dim.shape == (sum(grid.action_space.nvec),)
    np.testing.assert_array_equal(per_dim[:60], joint.any(axis=(1, 2)))
    x, y, o = np.argwhere(joint)[-1]
    index = int(np.ravel_multi_index((x, y, o), joint.shape))
    _, r_flat, *_ = flat.step(index)
    _, r_grid, *_ = grid.step(np.array([x, y, o]))
    assert float(r_flat) == float(r_grid) > 0
    np.testing.assert_array_equal(_pack(flat).action_mask(), _pack(grid).action_mask())
    with pytest.raises(ValueError, match="one index"):
        flat.step(np.array([1, 2, 0]))


def test_registered_on_import_robobpp_with_a_step_limit():
    import subprocess
    import sys

    code = (
        "import sys, gymnasium as gym, robobpp\n"
        "assert 'robobpp.env' not in sys.modules\n"
        "spec = gym.spec('robobpp/Pack-v0')\n"
        "print(spec.entry_point, spec.max_episode_steps)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.split() == ["robobpp.env:PackEnv", str(robobpp.GYM_MAX_EPISODE_STEPS)]


@pytest.mark.network
def test_train_ppo_example_trains_plots_and_evaluates(real_data, tmp_path):
    """A few hundred MaskablePPO steps end to end: model, learning curve, `robobpp evaluate` of the agent.

    Without a terminal (stdout a pipe, as in a batch job) it prints progress lines while it trains, and the
    curve file already holds the episodes a progress line counts when that line appears."""
    pytest.importorskip("sb3_contrib", reason="needs the learn extra: pip install -e '.[learn]'")
    import csv
    import json
    import os
    import re
    import subprocess
    import sys
    from pathlib import Path

    example = Path(__file__).resolve().parents[2] / "examples" / "train_ppo.py"
    cmd = [
        sys.executable,
        str(example),
        "--steps",
        "256",
        "--n-steps",
        "128",
        "--envs",
        "1",
        "--eval-groups",
        "1",
        "--no-baselines",
        "--progress-s",
        "0",
        "--out",
        str(tmp_path),
    ]
    env = {**os.environ, "ROBOBPP_DATA_DIR": str(real_data), "OMP_NUM_THREADS": "1"}
    err = (tmp_path / "stderr.txt").open("w")  # a file, not a pipe nobody reads while stdout is read
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, env=env)
    progress, written = [], []
    assert proc.stdout is not None
    for line in proc.stdout:  # read as printed: the curve on disk is checked at each progress line
        m = re.match(r"step (\d+)/256  episodes (\d+)  Space Utilization: last ([\d.]+)", line)
        if m:
            progress.append(line)
            written.append((int(m.group(2)), len((tmp_path / "curve.csv").read_text().splitlines()) - 1))
    proc.wait(timeout=300)
    err.close()
    assert proc.returncode == 0, (tmp_path / "stderr.txt").read_text()[-2000:]
    assert len(progress) >= 2, progress
    assert all(on_disk >= counted for counted, on_disk in written), written
    rows = list(csv.DictReader((tmp_path / "curve.csv").open()))
    assert len(rows) >= 2 and all(0 < float(r["space_utilization"]) <= 1 for r in rows)
    assert len(rows) >= written[-1][0]
    assert (tmp_path / "model.zip").stat().st_size > 0
    assert (tmp_path / "learning_curve.png").read_bytes()[:4] == b"\x89PNG"
    result = json.loads((tmp_path / "eval-ppopolicy.json").read_text())
    assert result["policy"] == "ppo" and result["episodes"][0]["boxes_placed"] >= 1


def test_maskable_ppo_predicts_on_the_default_dict_observation(specs):
    """MaskablePPO on the env as made (lookahead=0, Dict observation): an empty lookahead array made
    ``predict`` fail with "cannot reshape array of size 0 into shape (0,4)"."""
    pytest.importorskip("sb3_contrib", reason="needs the learn extra: pip install -e '.[learn]'")
    from sb3_contrib import MaskablePPO

    env = gym.make("robobpp/Pack-v0", specs=specs[:1], actions="flat")
    assert isinstance(env.observation_space, gym.spaces.Dict)
    assert "lookahead" not in env.observation_space.spaces  # nothing to show: no empty array either
    model = MaskablePPO("MultiInputPolicy", env, n_steps=16, batch_size=16, device="cpu", seed=0)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, action_masks=_pack(env).action_masks(), deterministic=True)
    assert _pack(env).action_masks()[int(action)]
    model.learn(16)  # a rollout and an update on the same observation space
    look = gym.make("robobpp/Pack-v0", specs=specs[:1], actions="flat", lookahead=2)
    assert look.reset(seed=0)[0]["lookahead"].shape == (2, 4)


@pytest.mark.parametrize("setting", ["math", "physics"])
def test_the_action_mask_is_bounds_and_height_and_support_comes_apart(setting):
    # a 4 × 10 × 5 block at the back, then a 10 × 10 × 1 slab: with its min corner at x < 4 it rests on the block
    # alone, its centre beyond the block's edge, which the reference's support rule refuses; at x ≥ 4 it lies
    # on the floor. The environment accepts both (bounds and height, as the reference's); the rule is offered
    # apart, in info["support_mask"], and only on a state observed after physics.
    specs = [make_spec([(4, 10, 5), (10, 10, 1)], (20, 10, 20))]
    env = _pack(gym.make("robobpp/Pack-v0", specs=specs, setting=setting, actions="flat", support_info=True))
    _, info = env.reset(seed=0)
    np.testing.assert_array_equal(info["support_mask"], info["action_masks"])  # nothing placed: all supported
    _, _, terminated, _, info = env.step(np.ravel_multi_index((0, 0, 0), env.grid_shape))
    assert info["placed"] and not terminated
    mask, support = env.action_mask(), env.support_mask()
    assert mask[:11, 0, 0].all()  # x = 0..10 fit (10 = 20 − 10)
    np.testing.assert_array_equal(info["action_masks"], env.action_masks())
    np.testing.assert_array_equal(info["support_mask"], support.reshape(-1))
    assert not (support & ~mask).any()  # the support mask narrows the action mask
    if setting == "math":
        np.testing.assert_array_equal(support, mask)
    else:
        assert not support[:4, :, 0].any() and support[4:11, 0, 0].all()
    # an action the rule refuses is still accepted and placed; gravity decides what happens to it
    _, reward, _, _, info = env.step(np.ravel_multi_index((0, 0, 0), env.grid_shape))
    assert info["placed"] and float(reward) > 0 and info.get("termination") != "unsupported"
    env.close()
    # by default the support mask is computed only when asked (it tests every position): not in info
    plain = _pack(gym.make("robobpp/Pack-v0", specs=specs, setting=setting))
    _, info = plain.reset(seed=0)
    assert "support_mask" not in info and plain.support_mask().any()
    plain.close()


def _masked_random_episode(env: gym.Env, rng: np.random.Generator) -> tuple[str, int]:
    """Draw every action from the env's own mask as MaskablePPO does (per dimension for a MultiDiscrete space):
    (how the episode ended, steps)."""
    pack = _pack(env)
    env.reset(seed=int(rng.integers(1 << 30)))
    steps, terminated = 0, False
    info: dict[str, Any] = {}
    while not terminated:
        masks = pack.action_masks()
        if isinstance(env.action_space, gym.spaces.Discrete):
            action = rng.choice(np.flatnonzero(masks))
        else:
            assert isinstance(env.action_space, gym.spaces.MultiDiscrete)
            nvec, start, action = env.action_space.nvec, 0, []
            for n in nvec:
                action.append(rng.choice(np.flatnonzero(masks[start : start + n])))
                start += n
            action = np.array(action)
        _, _, terminated, _, info = env.step(action)
        steps += 1
    return info["termination"], steps


def test_an_agent_that_draws_from_the_default_mask_never_picks_an_infeasible_action(specs):
    """The default (flat) mask is exact; the per-dimension mask of actions="grid" admits combinations that are
    not feasible, and an agent drawing from it ends episodes on them."""
    rng = np.random.default_rng(0)
    flat = gym.make("robobpp/Pack-v0", specs=specs)
    endings = [_masked_random_episode(flat, rng)[0] for _ in range(10)]
    assert set(endings) <= {"completed", "no_feasible_placement"}, endings
    with pytest.warns(UserWarning):
        grid = gym.make("robobpp/Pack-v0", specs=specs, actions="grid")
    endings = [_masked_random_episode(grid, rng)[0] for _ in range(10)]
    assert any(e not in ("completed", "no_feasible_placement") for e in endings), endings


@pytest.mark.network
def test_each_reset_draws_a_group_of_the_whole_split_on_demand(real_data):
    """Without ``groups`` any group of the split, drawn at reset (nothing drawn ahead); a group is the same
    sequence ``episode_specs`` gives; ``groups=N`` keeps to the first N."""
    from robobpp.datasets import episode_specs

    env = _pack(gym.make("robobpp/Pack-v0", dataset="repetitive"))
    assert env.specs == []  # nothing drawn when the env is made
    groups = {int(env.reset(seed=s)[1]["episode_id"].rsplit("-", 1)[1]) for s in range(5)}
    assert len(groups) == 5 and max(groups) > 1000  # from the whole split, not a fixed first hundred
    env.reset(seed=0, options={"group": 7})
    assert _episode(env).spec.boxes == episode_specs("repetitive", "train", groups=8)[7].boxes
    again = _pack(gym.make("robobpp/Pack-v0", dataset="repetitive"))
    assert again.reset(seed=3)[1]["episode_id"] == env.reset(seed=3)[1]["episode_id"]  # seeded
    few = _pack(gym.make("robobpp/Pack-v0", dataset="repetitive", groups=3))
    assert {few.reset(seed=s)[1]["episode_id"][-3:] for s in range(20)} <= {"000", "001", "002"}
    with pytest.raises(ValueError, match="groups must be"):
        robobpp.env.PackEnv(dataset="repetitive", groups=0)


def test_the_kept_heightmap_channel_is_the_whole_heightmap_converted_after_any_raises():
    """Raises in any order, overlapping, below and above the container's top (clipped), several between two
    observations, and a replaced heightmap: the channel is what converting the whole heightmap gives."""
    from robobpp.core import ContainerSpec, ContainerState, Placement

    rng = np.random.default_rng(5)
    container = ContainerSpec(20, 16, 10)
    channel = robobpp.env._Channel(container.height)
    state = ContainerState(container)
    clipped = False
    for index in range(60):
        x, y = (float(v) for v in rng.integers(0, (18, 14)))
        length, width = (float(v) for v in rng.integers(1, 6, 2))
        z = float(rng.uniform(0, 9))
        placement = Placement(x, y, z, length, width, float(rng.uniform(0.1, 3)), 0, index)
        clipped = clipped or placement.top > container.height
        state.add(placement)
        if index % 3:  # sometimes two or three raises between observations
            continue
        expected = robobpp.env.heightmap_channel(state.heightmap, container.height)
        np.testing.assert_array_equal(channel(state), expected)
    assert clipped
    state.heightmap = np.full(container.grid_shape, 3.25)
    np.testing.assert_array_equal(channel(state)[0], np.full(container.grid_shape, 3.25, np.float32))
