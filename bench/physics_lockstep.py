"""Where do the default (fast) and the full simulation part? (docs/validation/physics.md, "Fidelity").

Runs one real episode in both modes side by side, each with its own copy of the policy, and stops at the
first step where the two policies choose differently: prints the step, both actions, how many heightmap
cells differ between the two observations (and a few of them), and how far apart each placed box is in the
two observations (mm).

    cd bench && nice python physics_lockstep.py diverse dbl 0
    cd bench && nice python physics_lockstep.py longboard hm 1 --option heightmap_shrink_cm=0.5
"""

from __future__ import annotations

import argparse

import numpy as np

from robobpp.datasets import episode_specs
from robobpp.episode import Episode
from robobpp.policies import load_policy
from robobpp.sim.physics import PhysicsPack


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("dataset")
    parser.add_argument("policy")
    parser.add_argument("group", type=int)
    parser.add_argument("--option", action="append", default=[], help="a PhysicsConfig field=value for both")
    args = parser.parse_args()
    options = {k: float(v) for k, v in (o.split("=", 1) for o in args.option)}
    spec = episode_specs(args.dataset, groups=args.group + 1)[args.group]
    episodes = {mode: Episode(spec, PhysicsPack(mode=mode, **options)) for mode in ("fast", "full")}  # type: ignore[arg-type]
    policies = {mode: load_policy(args.policy) for mode in episodes}
    for mode, episode in episodes.items():
        policies[mode].reset(episode.info)
    for step in range(len(spec.boxes)):
        obs = {mode: episode.observe() for mode, episode in episodes.items()}
        acts = {mode: policies[mode].act(obs[mode]) for mode in episodes}
        keys = {m: None if a is None else (a.x, a.y, a.orientation) for m, a in acts.items()}
        if keys["fast"] != keys["full"]:
            diff = obs["fast"].heightmap - obs["full"].heightmap
            cells = np.argwhere(np.abs(diff) > 1e-9)
            some = [
                (
                    tuple(int(v) for v in c),
                    float(obs["fast"].heightmap[tuple(c)]),
                    float(obs["full"].heightmap[tuple(c)]),
                )
                for c in cells[:4]
            ]
            print(
                f"{args.dataset} {args.policy} group {args.group}: first different action at step {step}: "
                f"fast {keys['fast']}, full {keys['full']}"
            )
            print(
                f"  heightmap cells that differ: {len(cells)}, max {np.abs(diff).max():.2f} cm, e.g. "
                f"(cell, fast cm, full cm) {some}"
            )
            fast = np.array([[p.x, p.y, p.z] for p in obs["fast"].placed])
            full = np.array([[p.x, p.y, p.z] for p in obs["full"].placed])
            print(
                "  observed placements, max |fast - full| per box (mm):",
                np.round(np.abs(fast - full).max(axis=1) * 10, 2).tolist(),
            )
            return
        for mode, episode in episodes.items():
            episode.step(acts[mode], 0.0)
        if any(e.done for e in episodes.values()):
            print(
                f"{args.dataset} {args.policy} group {args.group}: the same actions until step {step}; "
                f"fast {episodes['fast'].termination}, full {episodes['full'].termination}"
            )
            return


if __name__ == "__main__":
    main()
