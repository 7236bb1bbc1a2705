"""Steps per second of the Gym env (``robobpp/Pack-v0``, Math Pack) on one core, and Jumanji's BinPack beside it.

A masked random agent steps the env as made by ``gym.make`` (default flat actions, Repetitive, a train group drawn
per reset): each action is drawn from ``info["action_masks"]``, and an episode that ends is reset at once. A run
is ``--steps`` such steps from a fixed seed, so every run does the same work; the figure is the median of
``--runs`` runs, in steps per second: of the env alone (the time spent in ``env.step`` and ``env.reset``), and of
the whole loop (the agent's draw, a ``flatnonzero`` over the mask, included). The process is pinned to one core
where the OS allows it.

When ``jumanji`` is importable (``pip install jax jaxlib jumanji``; not a robobpp dependency), its ``BinPack-v2``
is timed in the same process with the same kind of agent (a masked random draw, jitted with the step, episodes
reset automatically). It is a different problem and a different design, so its figures are no like-for-like
comparison: 20 items per episode by default instead of a stream of boxes onto a 1 cm grid, an action space of
(empty maximal space, item) pairs, and everything compiled with jit; the single-env figure (one jitted call per
step from Python) and the vmapped one (``--jumanji-batch`` envs per call, steps counted over all of them) are
printed separately. XLA is held to one thread.

    python bench/bench_env_speed.py --steps 20000 --runs 5
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from _common import machine, median

# Before jax may be imported: one core, one XLA thread.
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")
os.environ.setdefault("JAX_PLATFORMS", "cpu")


def robobpp_run(steps: int, seed: int, dataset: str, actions: str = "flat") -> tuple[float, float]:
    """One run of the masked random agent in the Math env: (steps/s counting only the time in ``env.step`` and
    ``env.reset``, steps/s of the whole loop with the agent's draw)."""
    import robobpp  # noqa: F401 - registers robobpp/Pack-v0

    env = gym.make("robobpp/Pack-v0", dataset=dataset, setting="math", actions=actions)
    rng = np.random.default_rng(seed)
    clock = time.perf_counter
    _, info = env.reset(seed=seed)
    in_env = 0.0
    start = clock()
    for _ in range(steps):
        action = int(rng.choice(np.flatnonzero(info["action_masks"])))
        t0 = clock()
        _, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            _, info = env.reset()
        in_env += clock() - t0
    elapsed = clock() - start
    env.close()
    return steps / in_env, steps / elapsed


def jumanji_runs() -> tuple[Callable[[int, int], float], Callable[[int, int, int], float]] | None:
    """(single-env run, vmapped run) over Jumanji's BinPack-v2, or None when jumanji is not importable."""
    try:
        import jax
        import jax.numpy as jnp
        import jumanji
        from jumanji.wrappers import AutoResetWrapper, VmapAutoResetWrapper
    except ImportError:
        return None

    def masked_random(key: jax.Array, mask: jax.Array) -> jax.Array:
        flat = jax.random.categorical(key, jnp.where(mask.reshape(-1), 0.0, -jnp.inf))
        return jnp.stack(jnp.divmod(flat, mask.shape[-1])).astype(jnp.int32)

    def single(steps: int, seed: int) -> float:
        env = AutoResetWrapper(jumanji.make("BinPack-v2"))

        @jax.jit
        def act(state: Any, timestep: Any, key: Any) -> tuple[Any, Any, Any]:
            key, sub = jax.random.split(key)
            state, timestep = env.step(state, masked_random(sub, timestep.observation.action_mask))
            return state, timestep, key

        key = jax.random.PRNGKey(seed)
        state, timestep = jax.jit(env.reset)(key)
        jax.block_until_ready(act(state, timestep, key))  # compile outside the timing
        start = time.perf_counter()
        for _ in range(steps):
            state, timestep, key = act(state, timestep, key)
        jax.block_until_ready(state)
        return steps / (time.perf_counter() - start)

    def batched(steps: int, seed: int, batch: int) -> float:
        env = VmapAutoResetWrapper(jumanji.make("BinPack-v2"))

        @jax.jit
        def act(state: Any, timestep: Any, key: Any) -> tuple[Any, Any, Any]:
            key, sub = jax.random.split(key)
            keys = jax.random.split(sub, batch)
            actions = jax.vmap(masked_random)(keys, timestep.observation.action_mask)
            state, timestep = env.step(state, actions)
            return state, timestep, key

        key = jax.random.PRNGKey(seed)
        state, timestep = jax.jit(env.reset)(jax.random.split(key, batch))
        jax.block_until_ready(act(state, timestep, key))
        calls = max(1, steps // batch)
        start = time.perf_counter()
        for _ in range(calls):
            state, timestep, key = act(state, timestep, key)
        jax.block_until_ready(state)
        return calls * batch / (time.perf_counter() - start)

    return single, batched


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000, help="steps per run")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dataset", default="repetitive")
    parser.add_argument(
        "--actions", default="flat", choices=("flat", "candidates"), help="the env's action space"
    )
    parser.add_argument("--no-jumanji", action="store_true", help="time robobpp only")
    parser.add_argument("--jumanji-batch", type=int, default=256, help="envs per vmapped Jumanji call")
    args = parser.parse_args()
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else "?"
    print(f"{machine()}; pinned to core(s) {cores}")
    print(f"{args.runs} runs of {args.steps} steps, median\n")
    print("| env | steps/s (median) | runs |")
    print("|---|---|---|")

    def row(name: str, figures: list[float]) -> None:
        print(f"| {name} | {median(figures):,.0f} | {', '.join(f'{f:,.0f}' for f in figures)} |", flush=True)

    ours = [robobpp_run(args.steps, args.seed, args.dataset, args.actions) for _ in range(args.runs)]
    name = f"robobpp/Pack-v0, Math, {args.dataset}, {args.actions} actions"
    row(f"{name}: env.step + env.reset", [env for env, _ in ours])
    row(f"{name}: the loop, agent's draw included", [loop for _, loop in ours])
    if args.no_jumanji:
        return
    runs = jumanji_runs()
    if runs is None:
        print("\njumanji is not importable (pip install jax jaxlib jumanji): its BinPack was not timed.")
        return
    single, batched = runs
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # jumanji's own dtype promotion, every call
        row("Jumanji BinPack-v2, one env, jit", [single(args.steps, args.seed) for _ in range(args.runs)])
        batch = args.jumanji_batch
        row(
            f"Jumanji BinPack-v2, {batch} envs, jit + vmap",
            [batched(args.steps, args.seed, batch) for _ in range(args.runs)],
        )


if __name__ == "__main__":
    main()
