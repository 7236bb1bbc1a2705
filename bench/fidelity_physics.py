"""Fast mode against the full dynamic simulation on REAL train groups (CI runs the synthetic fidelity test;
this is the same comparison on the benchmark's own data, too slow for CI).

    python bench/fidelity_physics.py [--groups 5] [--policies dbl,hm]

Reports, per dataset: same termination, same boxes placed, and the local-stability difference on episodes that
neither run ended by a collapse (after a collapse, where falling boxes land is chaotic in both modes).
"""

from __future__ import annotations

import argparse
import time

from _common import machine

from robobpp.datasets import DATASETS, episode_specs
from robobpp.episode import run_episode
from robobpp.policies import load_policy
from robobpp.sim.physics import PhysicsPack


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--groups", type=int, default=5)
    parser.add_argument("--policies", default="dbl,hm")
    args = parser.parse_args()
    print(f"machine: {machine()}")
    print("| dataset | episodes | same termination | same boxes placed | compared (no collapse) "
          "| max LS diff (mm) | fast CPU s | full CPU s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for name in DATASETS:
        n = same_term = same_boxes = compared = 0
        worst = 0.0
        cpu = {"fast": 0.0, "full": 0.0}
        for policy in args.policies.split(","):
            for spec in episode_specs(name, groups=args.groups):
                results = {}
                for mode in ("fast", "full"):
                    t0 = time.process_time()
                    results[mode] = run_episode(spec, load_policy(policy), PhysicsPack(mode=mode))
                    cpu[mode] += time.process_time() - t0
                fast, full = results["fast"], results["full"]
                n += 1
                same_term += fast.termination == full.termination
                same_boxes += fast.boxes_placed == full.boxes_placed
                if "collapse" not in (fast.termination, full.termination):
                    compared += 1
                    diff = abs(
                        (fast.metrics["local_stability"] or 0) - (full.metrics["local_stability"] or 0)
                    )
                    worst = max(worst, diff * 1000)
        print(f"| {name} | {n} | {same_term}/{n} | {same_boxes}/{n} | {compared} | {worst:.2f} "
              f"| {cpu['fast']:.0f} | {cpu['full']:.0f} |")  # fmt: skip


if __name__ == "__main__":
    main()
