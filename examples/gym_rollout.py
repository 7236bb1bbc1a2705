"""Roll out a masked greedy agent in the Gymnasium env: the loop an RL trainer runs, without the learning.

python examples/gym_rollout.py --dataset repetitive --setting math --episodes 3

Each episode plays a different train group, drawn with ``--seed`` (no group twice until all ``--groups`` were
played). The agent scores the feasible actions of ``action_mask()`` by "lowest resting height, then back-left" from the
observed heightmap: a DBL-like rule written against the env's own observation and action spaces.
"""

import argparse
from typing import cast

import gymnasium as gym
import numpy as np

import robobpp  # noqa: F401 - importing robobpp registers robobpp/Pack-v0
from robobpp.core import drop_height_map
from robobpp.env import PackEnv


def greedy_action(obs: dict[str, np.ndarray], mask: np.ndarray) -> np.ndarray | None:
    """The feasible (x, y, orientation) whose footprint rests lowest; ties back-left (vectorised); None when
    nothing is feasible (the env has then already ended the episode)."""
    heightmap, (length, width, _, _) = obs["heightmap"][0], obs["box"]  # (1, nx, ny): one image channel
    best, best_cost = None, np.inf
    for o, (lx, wy) in enumerate(((length, width), (width, length))):
        z = drop_height_map(heightmap, lx, wy)  # resting height at every (x, y)
        if z.size == 0:
            continue
        nx, ny = z.shape
        cost = 100 * z + np.arange(nx)[:, None] + np.arange(ny)[None, :]
        cost = np.where(mask[:nx, :ny, o], cost, np.inf)
        x, y = np.unravel_index(np.argmin(cost), cost.shape)
        if cost[x, y] < best_cost:
            best, best_cost = np.array([x, y, o]), cost[x, y]
    return best


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--dataset", default="repetitive")
    parser.add_argument("--setting", default="math")
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--groups", type=int, default=10, help="train groups the env draws episodes from")
    parser.add_argument("--seed", type=int, default=0, help="seeds the order the groups are played in")
    args = parser.parse_args()
    env = gym.make("robobpp/Pack-v0", dataset=args.dataset, setting=args.setting, groups=args.groups)
    pack = cast(PackEnv, env.unwrapped)  # the env under gymnasium's wrappers: its action mask
    # A reset without options draws a group at random, so two episodes may meet the same one: play them in a
    # seeded order instead, each group once before any comes again.
    order = np.random.default_rng(args.seed).permutation(args.groups)
    for episode in range(args.episodes):
        group = int(order[episode % args.groups])
        obs, info = env.reset(seed=args.seed if episode == 0 else None, options={"group": group})
        episode_id = info["episode_id"]
        total, steps, terminated = 0.0, 0, False
        while not terminated:  # the env ends the episode itself when nothing fits the next box
            action = greedy_action(obs, pack.action_mask())
            assert action is not None, "the env ends an episode when nothing fits its next box"
            # the default action space is one Discrete index per (x, y, orientation) cell
            obs, reward, terminated, truncated, info = env.step(np.ravel_multi_index(action, pack.grid_shape))
            total += float(reward)
            steps += 1
        print(f"{episode_id}: {steps} boxes, return {total:.3f}, ended by {info['termination']}")
    env.close()


if __name__ == "__main__":
    main()
