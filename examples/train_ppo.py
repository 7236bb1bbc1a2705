"""Train a masked PPO agent on Math Pack Repetitive (train split) in the candidate space, plot its learning curve,
evaluate it on train groups it never saw, serve it.

    pip install torch --index-url https://download.pytorch.org/whl/cpu   # the CPU build: no CUDA wheels
    pip install -e '.[learn]'                    # sb3-contrib (MaskablePPO), matplotlib, tqdm; keeps that torch
    python examples/train_ppo.py --cpu-minutes 60 --out runs/ppo

On a terminal it shows a progress bar; otherwise (a batch job, output to a file) it prints a progress line at
most every ``--progress-s`` seconds.

The agent acts as the paper's learned methods do: in ``robobpp/Pack-v0`` with ``actions="candidates"``, it picks
one of at most 50 candidate placements of the box (the reference PCT's leaf nodes), masked to the real ones
(``action_masks()``). One small network scores every candidate from its features and the box (the same weights
for each candidate, :class:`CandidateEncoder` and :class:`CandidatePolicy`), so what it learns about a placement
holds wherever the placement is; the value is read from the mean of the candidates' embeddings. The reward is the
placed box's share of the container volume, so an episode's return is its Space Utilization. ``--envs 2`` steps
two envs in processes of their own (two cores).

It trains on groups drawn with sampling seed 1 and is evaluated (``robobpp evaluate``) on the train split's
groups of seed 0: the same pool, groups it never trained on.

Writes to ``--out``: ``curve.csv`` (Space Utilization of every training episode, a row as each ends; CPU seconds
of the whole run beside it), ``model.zip`` (the trained agent) and ``learning_curve.png`` (the curve and its
running mean), then evaluates the agent, Random and DBL with ``robobpp evaluate`` on the evaluation groups
(``eval-*.json``) and draws their figures on the plot. :class:`PPOPolicy` is the trained agent as a robobpp
policy, to evaluate::

    ROBOBPP_PPO_MODEL=runs/ppo/model.zip PYTHONPATH=examples robobpp evaluate --policy train_ppo:PPOPolicy

or to submit to a server in one command (pull mode: the agent runs here, no port to open)::

    ROBOBPP_PPO_MODEL=runs/ppo/model.zip PYTHONPATH=examples robobpp connect train_ppo:PPOPolicy \
        --server https://SERVER --token TOKEN --dataset repetitive --setting math
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import gymnasium as gym
import numpy as np

import robobpp  # noqa: F401 - importing robobpp registers robobpp/Pack-v0
from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.env import encode_observation
from robobpp.policies import BasePolicy
from robobpp.policies.candidate_space import CandidateSpace

try:
    import torch
    from sb3_contrib import MaskablePPO
    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
    from torch import nn
except ModuleNotFoundError as exc:  # say which extra brings it, in one line
    raise SystemExit(
        f"train_ppo needs {exc.name}, which is not installed: pip install 'robobpp[learn]'"
    ) from None

#: Width of a candidate's embedding.
EMBED = 64


class CandidateEncoder(BaseFeaturesExtractor):
    """Embeds every candidate with the same small network, from its features and the box's sides (scaled by the
    longest container side); the output is the candidates' mean embedding, then every candidate's."""

    def __init__(self, observation_space: gym.spaces.Dict, side: float) -> None:
        shape = observation_space["candidates"].shape
        assert shape is not None
        k, f = shape
        super().__init__(observation_space, features_dim=EMBED * (k + 1))
        self.k, self.side = k, side
        self.embed = nn.Sequential(nn.Linear(f + 3, EMBED), nn.ReLU(), nn.Linear(EMBED, EMBED), nn.ReLU())

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        cands = obs["candidates"]
        box = (obs["box"][:, :3] / self.side)[:, None, :].expand(-1, self.k, -1)
        each = self.embed(torch.cat([cands, box], dim=-1))
        valid = cands[..., :1]  # the "valid" feature: padding rows do not count in the mean
        mean = (each * valid).sum(1) / valid.sum(1).clamp(min=1.0)
        return torch.cat([mean, each.flatten(1)], dim=1)


class CandidateScores(nn.Module):
    """One logit per candidate: the same head on each candidate's embedding beside the mean one."""

    def __init__(self, k: int) -> None:
        super().__init__()
        self.k = k
        last = nn.Linear(EMBED, 1)
        nn.init.orthogonal_(last.weight, gain=0.01)  # near-uniform choice at first, as sb3 starts
        self.head = nn.Sequential(nn.Linear(2 * EMBED, EMBED), nn.ReLU(), last)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        mean, each = latent[:, :EMBED], latent[:, EMBED:].reshape(-1, self.k, EMBED)
        both = torch.cat([each, mean[:, None, :].expand(-1, self.k, -1)], dim=-1)
        logits: torch.Tensor = self.head(both).squeeze(-1)
        return logits


class MeanValue(nn.Module):
    """The value from the candidates' mean embedding (what does not depend on their order)."""

    def __init__(self) -> None:
        super().__init__()
        self.head = nn.Sequential(nn.Linear(EMBED, EMBED), nn.ReLU(), nn.Linear(EMBED, 1))

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        logits: torch.Tensor = self.head(latent[:, :EMBED])
        return logits


class CandidatePolicy(MaskableActorCriticPolicy):
    """MaskablePPO's actor-critic with :class:`CandidateScores` and :class:`MeanValue` as its heads."""

    def _build(self, lr_schedule: object) -> None:
        super()._build(lr_schedule)  # type: ignore[arg-type]
        extractor = self.features_extractor
        assert isinstance(extractor, CandidateEncoder)
        self.action_net = CandidateScores(extractor.k)
        self.value_net = MeanValue()  # type: ignore[assignment]  # sb3 declares a Linear; any module serves
        self.optimizer = self.optimizer_class(
            self.parameters(),
            lr=lr_schedule(1),  # type: ignore[call-arg,operator]
            **self.optimizer_kwargs,
        )


def make_env(dataset: str, seed: int) -> gym.Env:
    from stable_baselines3.common.monitor import Monitor

    # training groups: the train split drawn with sampling seed 1 (evaluation uses seed 0's groups)
    env = gym.make("robobpp/Pack-v0", dataset=dataset, setting="math", actions="candidates", data_seed=1)
    env.reset(seed=seed)
    return Monitor(env)


class Curve(BaseCallback):
    """Records (timestep, CPU s, Space Utilization) of every finished episode as it ends: appended to ``path``
    at once (a long run's curve can be read while it trains), and, when ``progress_s`` is set, a progress
    line on stdout at most every ``progress_s`` seconds (batch jobs have no terminal for a progress bar).
    Stops training at a time budget. CPU time counts this process and its env processes."""

    def __init__(self, cpu_s: float, wall_s: float, path: Path, total: int, progress_s: float | None) -> None:
        super().__init__()
        self.points: list[tuple[int, float, float]] = []
        self.cpu0 = cpu_seconds()
        self.cpu, self.cpu_read_at = 0.0, time.monotonic()
        self.budget = (cpu_s, time.monotonic() + wall_s)
        self.total, self.progress_s = total, progress_s
        self.started, self.last_line = time.monotonic(), -float("inf")
        self.file = path.open("w", newline="")
        self.csv = csv.writer(self.file)
        self.csv.writerow(("timestep", "cpu_s", "space_utilization"))
        self.file.flush()

    def _on_step(self) -> bool:
        # Reading every process's CPU time scans /proc (milliseconds): once an episode ends, or a second has
        # passed, not on every step.
        ended = any("episode" in info for info in self.locals["infos"])
        if ended or time.monotonic() - self.cpu_read_at >= 1.0:
            self.cpu, self.cpu_read_at = cpu_seconds() - self.cpu0, time.monotonic()
        cpu = self.cpu
        for info in self.locals["infos"]:
            if "episode" in info:  # added by sb3's Monitor at the end of an episode: r = the return
                point = (self.num_timesteps, round(cpu, 1), float(info["episode"]["r"]))
                self.points.append(point)
                self.csv.writerow(point)
                self.file.flush()
                self._progress(cpu)
        return cpu < self.budget[0] and time.monotonic() < self.budget[1]

    def _progress(self, cpu: float) -> None:
        now = time.monotonic()
        if self.progress_s is None or now - self.last_line < self.progress_s:
            return
        self.last_line = now
        recent = [p[2] for p in self.points[-100:]]
        print(
            f"step {self.num_timesteps}/{self.total}  episodes {len(self.points)}  Space Utilization: last "
            f"{recent[-1]:.3f}, mean of last {len(recent)} {np.mean(recent):.3f}  "
            f"{cpu / 60:.1f} CPU-min, {(now - self.started) / 60:.1f} min",
            flush=True,
        )

    def _on_training_end(self) -> None:
        self.file.close()


def cpu_seconds() -> float:
    """CPU time of this process and every process under it, running or finished (the env processes are the
    children of multiprocessing's fork server, itself a child of this one)."""
    import resource

    finished = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + finished.ru_utime + finished.ru_stime + sum(_descendants_cpu().values())


def _descendants_cpu() -> dict[int, float]:
    """CPU seconds of each running process below this one (Linux /proc; empty elsewhere)."""
    parents: dict[int, int] = {}
    cpu: dict[int, float] = {}
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue  # ended while read
        pid = int(stat.parent.name)
        parents[pid] = int(fields[1])
        cpu[pid] = (int(fields[11]) + int(fields[12])) / tick
    below, frontier = {}, [os.getpid()]
    while frontier:
        parent = frontier.pop()
        for pid, ppid in parents.items():
            if ppid == parent and pid not in below:
                below[pid] = cpu[pid]
                frontier.append(pid)
    return below


class PPOPolicy(BasePolicy):
    """A trained agent (``ROBOBPP_PPO_MODEL``, default runs/ppo/model.zip) as a robobpp policy: the same candidate
    list the env gave it (seeded by the episode), its most probable candidate."""

    name = "ppo"

    def __init__(self, model: str | None = None) -> None:
        path = Path(model or os.environ.get("ROBOBPP_PPO_MODEL", "runs/ppo/model.zip"))
        if not path.is_file():
            raise SystemExit(
                f"no trained model at {path}: train one with examples/train_ppo.py, or set ROBOBPP_PPO_MODEL"
            )
        self.model = MaskablePPO.load(path, device="cpu")
        space = self.model.observation_space
        assert isinstance(space, gym.spaces.Dict)
        shape = space["candidates"].shape
        assert shape is not None
        limit = shape[0]
        self.space = CandidateSpace(limit)

    def reset(self, info: EpisodeInfo) -> None:
        self.space.reset(info.container, info.episode_id)

    def act(self, obs: Observation) -> Action | None:
        candidates = self.space(obs)
        if not candidates.mask.any():
            return None
        x = encode_observation(obs, 0, candidates)
        index, _ = self.model.predict(x, action_masks=candidates.mask, deterministic=True)
        return candidates.action(int(index))


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
    ax.set_title("MaskablePPO on candidates, Math Pack (train split)", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--dataset", default="repetitive")
    parser.add_argument("--steps", type=int, default=2_000_000, help="environment steps (boxes) to train for")
    parser.add_argument(
        "--cpu-minutes",
        type=float,
        default=float("inf"),
        help="stop training after this CPU time (all processes)",
    )
    parser.add_argument(
        "--wall-minutes", type=float, default=float("inf"), help="stop training after this wall time"
    )
    parser.add_argument(
        "--envs", type=int, default=2, help="envs stepped in processes of their own (1: in this one)"
    )
    parser.add_argument("--n-steps", type=int, default=1024, help="steps per env per PPO rollout")
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

    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    from robobpp.datasets.registry import get_dataset

    container = get_dataset(args.dataset).container
    side = float(max(container.length, container.width, container.height))
    makers: list[Callable[[], gym.Env]] = [
        partial(make_env, args.dataset, args.seed + i) for i in range(args.envs)
    ]
    env = SubprocVecEnv(makers) if args.envs > 1 else DummyVecEnv(makers)
    model = MaskablePPO(
        CandidatePolicy,
        env,
        policy_kwargs={
            "features_extractor_class": CandidateEncoder,
            "features_extractor_kwargs": {"side": side},
            "net_arch": [],
        },
        n_steps=args.n_steps,
        batch_size=256,
        learning_rate=3e-4,
        gamma=1.0,
        ent_coef=0.01,
        seed=args.seed,
        device="cpu",
        verbose=0,
    )
    torch.set_num_threads(1)  # one core: the figures in docs are per CPU-minute
    start = cpu_seconds()
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
        f"{(cpu_seconds() - start) / 60:.1f} CPU-minutes (all processes); model in {args.out / 'model.zip'}"
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
