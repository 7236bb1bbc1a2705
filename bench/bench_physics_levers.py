"""Where the full simulation spends its CPU per box, and what each speed lever saves and changes.

One real train episode (default: Repetitive group 0, LSAH) in the full simulation under cProfile, then the
same episode with each lever on its own:

- ``sleeping``: Bullet's deactivation of resting bodies (islands at rest for 2 s stop being solved);
- ``solver10``: 10 constraint-solver iterations instead of 50;
- ``fast``: the default mode (simulate only the boxes a placement can touch, stop once at rest).

    python bench/bench_physics_levers.py [--dataset repetitive] [--group 0] [--policy lsah]

Prints the profile's top entries and, per lever, CPU-s per box and how the episode ended against full.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import pybullet as p
from _common import CpuPerStep, machine, median

from robobpp.datasets import episode_specs
from robobpp.episode import EpisodeResult, run_episode
from robobpp.policies import load_policy
from robobpp.sim.physics import PhysicsPack, PhysicsWorld


@contextmanager
def sleeping() -> Iterator[None]:
    """Every box created may be deactivated by Bullet once its island rests (off by default in pybullet)."""
    original = PhysicsWorld.add_box

    def add_box(self: PhysicsWorld, *args: Any, **kwargs: Any) -> Any:
        box = original(self, *args, **kwargs)
        p.changeDynamics(
            box.body, -1, activationState=p.ACTIVATION_STATE_ENABLE_SLEEPING, physicsClientId=self.client
        )
        return box

    PhysicsWorld.add_box = add_box  # type: ignore[method-assign]
    try:
        yield
    finally:
        PhysicsWorld.add_box = original  # type: ignore[method-assign]


@contextmanager
def nothing() -> Iterator[None]:
    yield


LEVERS: dict[str, tuple[dict[str, Any], Callable[[], Any]]] = {
    "full": ({"mode": "full"}, nothing),
    "sleeping": ({"mode": "full"}, sleeping),
    "solver10": ({"mode": "full", "solver_iterations": 10}, nothing),
    "fast": ({"mode": "fast"}, nothing),
}


def run(spec: Any, policy: str, options: dict[str, Any]) -> tuple[EpisodeResult, list[float]]:
    clock = CpuPerStep()
    return run_episode(spec, load_policy(policy), PhysicsPack(**options), on_step=clock), clock.per_box


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--dataset", default="repetitive")
    parser.add_argument("--group", type=int, default=0)
    parser.add_argument("--policy", default="lsah")
    args = parser.parse_args()
    spec = episode_specs(args.dataset, groups=args.group + 1)[args.group]
    print(f"machine: {machine()}; {args.dataset} group {args.group}, {args.policy}")
    profiler = cProfile.Profile()
    profiler.enable()
    run(spec, args.policy, {"mode": "full"})
    profiler.disable()
    text = io.StringIO()
    pstats.Stats(profiler, stream=text).sort_stats("tottime").print_stats(8)
    print("\n".join(line for line in text.getvalue().splitlines() if line.strip())[:3000])
    print("| lever | CPU-s/box median | CPU-s/box mean | termination | boxes placed | Local Stab. (mm) |")
    print("|---|---|---|---|---|---|")
    for name, (options, patch) in LEVERS.items():
        with patch():
            result, per_box = run(spec, args.policy, options)
        ls = (result.metrics.get("local_stability") or 0.0) * 1000
        print(
            f"| {name} | {median(per_box):.4f} | {sum(per_box) / len(per_box):.4f} | {result.termination} "
            f"| {result.boxes_placed} | {ls:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
