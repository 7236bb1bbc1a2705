"""Train a masked PPO agent on Math Pack Repetitive (train split), plot its learning curve, evaluate it.

    pip install torch --index-url https://download.pytorch.org/whl/cpu   # the CPU build: no CUDA wheels
    pip install -e '.[learn]'                    # sb3-contrib (MaskablePPO), matplotlib, tqdm; keeps that torch
    python examples/train_ppo.py --steps 100000 --out runs/ppo

On a terminal it shows a progress bar; otherwise (a batch job, output to a file) it prints a progress line at
most every ``--progress-s`` seconds.

The agent acts in ``robobpp/Pack-v0`` with ``actions="flat"``: one Discrete action per (x, y, orientation)
cell, masked by the env's ``action_masks()`` to the feasible ones, so every action it takes is a valid
placement. Its input is the heightmap and the box, scaled to [0, 1] (:func:`features`); the reward is the
placed box's share of the container volume, so an episode's return is its Space Utilization.

Writes to ``--out``: ``curve.csv`` (Space Utilization of every training episode, a row as each ends),
``model.zip`` (the trained agent) and ``learning_curve.png`` (the curve and its running mean), then evaluates the agent, Random and DBL with
``robobpp evaluate`` on the same train groups (``eval-*.json``) and draws their figures on the plot.
:class:`PPOPolicy` is the trained agent as a robobpp policy::

    ROBOBPP_PPO_MODEL=runs/ppo/model.zip PYTHONPATH=examples robobpp evaluate --policy train_ppo:PPOPolicy
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import cast

import gymnasium as gym
import numpy as np

import robobpp  # noqa: F401 - importing robobpp registers robobpp/Pack-v0
from robobpp.core import ORIENTATIONS, Action, ContainerSpec, Observation
from robobpp.env import PackEnv, encode_observation
from robobpp.policies import BasePolicy
from robobpp.policies.candidates import candidate_maps, first_placement

try:
    import torch
    from sb3_contrib import MaskablePPO
    from stable_baselines3.common.callbacks import BaseCallback
except ModuleNotFoundError as exc:  # say which extra brings it, in one line
    raise SystemExit(
        f"train_ppo needs {exc.name}, which is not installed: pip install 'robobpp[learn]'"
    ) from None


def features(obs: dict[str, np.ndarray], container: ContainerSpec) -> np.ndarray:
    """The agent's input: heightmap / container height, then the box's sides / the longest container side."""
    side = max(container.length, container.width, container.height)
    return np.concatenate([obs["heightmap"].ravel() / container.height, obs["box"][:3] / side]).astype(
        np.float32
    )


class Features(gym.ObservationWrapper):
    """The env's dict observation as the flat vector :func:`features` (what an MLP policy takes)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.container = cast(PackEnv, env.unwrapped).container
        size = int(np.prod(self.container.grid_shape)) + 3
        self.observation_space = gym.spaces.Box(0.0, np.inf, (size,), np.float32)

    def observation(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        return features(observation, self.container)


class Curve(BaseCallback):
    """Records (timestep, CPU s, Space Utilization) of every finished episode as it ends: appended to ``path``
    at once (a long run's curve can be read while it trains), and, when ``progress_s`` is set, a progress
    line on stdout at most every ``progress_s`` seconds (batch jobs have no terminal for a progress bar).
    Stops training at a time budget."""

    def __init__(self, cpu_s: float, wall_s: float, path: Path, total: int, progress_s: float | None) -> None:
        super().__init__()
        self.points: list[tuple[int, float, float]] = []
        self.budget = (time.process_time() + cpu_s, time.monotonic() + wall_s)
        self.total, self.progress_s = total, progress_s
        self.started, self.last_line = time.monotonic(), -float("inf")
        self.file = path.open("w", newline="")
        self.csv = csv.writer(self.file)
        self.csv.writerow(("timestep", "cpu_s", "space_utilization"))
        self.file.flush()

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            if "episode" in info:  # added by sb3's Monitor at the end of an episode: r = the return
                point = (self.num_timesteps, time.process_time(), float(info["episode"]["r"]))
                self.points.append(point)
                self.csv.writerow(point)
                self.file.flush()
                self._progress()
        return time.process_time() < self.budget[0] and time.monotonic() < self.budget[1]

    def _progress(self) -> None:
        now = time.monotonic()
        if self.progress_s is None or now - self.last_line < self.progress_s:
            return
        self.last_line = now
        recent = [p[2] for p in self.points[-20:]]
        print(
            f"step {self.num_timesteps}/{self.total}  episodes {len(self.points)}  Space Utilization: last "
            f"{recent[-1]:.3f}, mean of last {len(recent)} {np.mean(recent):.3f}  "
            f"{(now - self.started) / 60:.1f} min",
            flush=True,
        )

    def _on_training_end(self) -> None:
        self.file.close()


class PPOPolicy(BasePolicy):
    """A trained MaskablePPO agent (``ROBOBPP_PPO_MODEL``, default runs/ppo/model.zip) as a robobpp policy."""

    name = "ppo"

    def __init__(self, model: str | None = None) -> None:
        path = model or os.environ.get("ROBOBPP_PPO_MODEL", "runs/ppo/model.zip")
        self.model = MaskablePPO.load(path, device="cpu")

    def act(self, obs: Observation) -> Action | None:
        # The agent's most probable placement that fits (bounds and height: the env's action mask): the greedy
        # choice under the mask it was trained with.
        shape = (*obs.container.grid_shape, len(ORIENTATIONS))
        fits = np.zeros(shape, bool)
        for cand in candidate_maps(obs):
            cx, cy = cand.fits.shape
            fits[:cx, :cy, cand.orientation] = cand.fits
        if not fits.any():
            return None
        x = features(encode_observation(obs, 0), obs.container)
        tensor, _ = self.model.policy.obs_to_tensor(x)
        with torch.no_grad():
            distribution = self.model.policy.get_distribution(tensor, action_masks=fits.ravel()).distribution
            assert isinstance(distribution, torch.distributions.Categorical)  # one discrete action space
            probs = distribution.probs
        ranked = np.argsort(-probs[0].numpy(), kind="stable")
        ranked = ranked[fits.ravel()[ranked]]
        xs, ys, orientations = np.unravel_index(ranked, shape)
        return first_placement(range(len(ranked)), xs, ys, orientations)


def evaluate(policy: str, args: argparse.Namespace, out: Path, extra_env: dict[str, str]) -> float:
    """Mean Space Utilization of ``robobpp evaluate`` for one policy on the evaluation groups."""
    target = out / f"eval-{policy.split(':')[-1].lower()}.json"
    cmd = [
        "robobpp",
        "evaluate",
        "--policy",
        policy,
        "--dataset",
        args.dataset,
        "--setting",
        "math",
        "--groups",
        str(args.eval_groups),
        "--json",
        str(target),
    ]
    print("$", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, env={**os.environ, **extra_env})
    return float(json.loads(target.read_text())["runs"][0]["metrics"]["space_utilization"])


def plot(points: list[tuple[int, float, float]], lines: dict[str, float], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.array([p[0] for p in points])
    util = np.array([p[2] for p in points])
    window = max(1, len(util) // 20)
    mean = np.convolve(util, np.ones(window) / window, mode="valid") if len(util) else util
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(steps, util, ".", alpha=0.3, label="training episode")
    if len(mean):
        ax.plot(steps[window - 1 :], mean, label=f"running mean ({window})")
    for (name, value), style in zip(lines.items(), ("--", ":", "-."), strict=False):
        ax.axhline(value, linestyle=style, color="k", label=f"{name} (evaluate): {value:.3f}")
    ax.set_xlabel("environment steps (boxes)")
    ax.set_ylabel("Space Utilization")
    ax.set_title("MaskablePPO, Math Pack Repetitive (train split)")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--dataset", default="repetitive")
    parser.add_argument("--groups", type=int, default=100, help="train groups the env draws episodes from")
    parser.add_argument("--steps", type=int, default=100_000, help="environment steps (boxes) to train for")
    parser.add_argument(
        "--cpu-minutes", type=float, default=float("inf"), help="stop training after this CPU time"
    )
    parser.add_argument(
        "--wall-minutes", type=float, default=float("inf"), help="stop training after this wall time"
    )
    parser.add_argument("--n-steps", type=int, default=512, help="steps per PPO rollout")
    parser.add_argument("--eval-groups", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/ppo"))
    parser.add_argument("--no-baselines", action="store_true", help="evaluate only the agent, not Random/DBL")
    parser.add_argument(
        "--progress-s",
        type=float,
        default=30.0,
        help="without a terminal: a progress line at most this often (seconds; 0: every episode)",
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    from stable_baselines3.common.monitor import Monitor

    env = gym.make(
        "robobpp/Pack-v0", dataset=args.dataset, setting="math", groups=args.groups, actions="flat"
    )
    env = Monitor(Features(env))
    model = MaskablePPO(
        "MlpPolicy",
        env,
        n_steps=args.n_steps,
        batch_size=64,
        gamma=1.0,
        seed=args.seed,
        device="cpu",
        verbose=0,
    )
    torch.set_num_threads(1)  # one core: the figures in docs are per CPU-minute
    start = time.process_time()
    # On a terminal a progress bar; otherwise (batch jobs, logs) progress lines on stdout.
    terminal = sys.stderr.isatty()
    print(f"training {args.steps} steps; curve in {args.out / 'curve.csv'} as it goes", flush=True)
    curve = Curve(
        60 * args.cpu_minutes,
        60 * args.wall_minutes,
        args.out / "curve.csv",
        args.steps,
        None if terminal else args.progress_s,
    )
    model.learn(total_timesteps=args.steps, callback=curve, progress_bar=terminal)
    model.save(args.out / "model.zip")
    print(
        f"trained {model.num_timesteps} steps, {len(curve.points)} episodes in "
        f"{(time.process_time() - start) / 60:.1f} CPU-minutes; model in {args.out / 'model.zip'}"
    )

    examples = str(Path(__file__).resolve().parent)
    agent_env = {
        "ROBOBPP_PPO_MODEL": str(args.out / "model.zip"),
        "PYTHONPATH": os.pathsep.join(filter(None, [examples, os.environ.get("PYTHONPATH")])),
    }
    lines = {"PPO": evaluate("train_ppo:PPOPolicy", args, args.out, agent_env)}
    if not args.no_baselines:
        lines |= {name: evaluate(name.lower(), args, args.out, {}) for name in ("Random", "DBL")}
    plot(curve.points, lines, args.out / "learning_curve.png")
    print("Space Utilization:", ", ".join(f"{k} {v:.3f}" for k, v in lines.items()))


if __name__ == "__main__":
    main()
