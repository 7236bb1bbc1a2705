"""Does the Gym env's action mask let a masked agent pick an infeasible action? (robobpp/env.py, "Masks").

A masked random agent draws every action from the env's own ``action_masks()`` as sb3-contrib's MaskablePPO
does: from the flat mask for the default Discrete space, one value per dimension from the per-dimension masks
for ``actions="grid"`` (MultiDiscrete). Printed per action space: episodes, how many ended on an infeasible
action (a termination other than "completed" or "no_feasible_placement"), and the mean steps per episode.

    python bench/bench_env_masks.py --episodes 50 --dataset repetitive
"""

from __future__ import annotations

import argparse
import statistics
import warnings

import gymnasium as gym
import numpy as np

import robobpp  # noqa: F401 - registers robobpp/Pack-v0

FEASIBLE_ENDINGS = ("completed", "no_feasible_placement")


def masked_action(env: gym.Env, rng: np.random.Generator) -> np.ndarray | np.integer:
    masks = env.unwrapped.action_masks()  # type: ignore[attr-defined]
    if isinstance(env.action_space, gym.spaces.Discrete):
        action: np.integer = rng.choice(np.flatnonzero(masks))
        return action
    values, start = [], 0
    for n in env.action_space.nvec:  # type: ignore[attr-defined]
        values.append(rng.choice(np.flatnonzero(masks[start : start + n])))
        start += int(n)
    return np.array(values)


def run(actions: str, dataset: str, episodes: int, groups: int) -> tuple[int, float]:
    """(episodes ended on an infeasible action, mean steps per episode)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # actions="grid" warns about exactly what this measures
        env = gym.make("robobpp/Pack-v0", dataset=dataset, setting="math", groups=groups, actions=actions)
    rng = np.random.default_rng(0)
    infeasible, steps = 0, []
    for episode in range(episodes):
        env.reset(seed=episode)
        n, terminated, info = 0, False, dict[str, object]()
        while not terminated:
            _, _, terminated, _, info = env.step(masked_action(env, rng))
            n += 1
        infeasible += info["termination"] not in FEASIBLE_ENDINGS
        steps.append(n)
    env.close()
    return infeasible, statistics.mean(steps)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--dataset", default="repetitive")
    parser.add_argument("--groups", type=int, default=50, help="train groups the env draws episodes from")
    args = parser.parse_args()
    print("| action space | episodes | ended on an infeasible action | mean steps |")
    print("|---|---|---|---|")
    for actions, name in (("flat", "Discrete (default)"), ("grid", 'MultiDiscrete (actions="grid")')):
        infeasible, mean_steps = run(actions, args.dataset, args.episodes, args.groups)
        print(f"| {name} | {args.episodes} | {infeasible} | {mean_steps:.1f} |")


if __name__ == "__main__":
    main()
