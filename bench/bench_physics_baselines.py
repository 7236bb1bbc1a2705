"""Physics Pack figures of every baseline policy (``robobpp.policies.BASELINES``) on the train split.

For each dataset, the first ``--groups`` train groups (80 boxes each) are run with every baseline through
the one episode loop (``run_episode``, which measures Decision Time itself) in the default Physics Pack,
and the per-episode metrics are averaged: Space Utilization, Occupancy, Decision Time, Local Stability,
Static Stability, boxes placed, and how the episodes ended. Geometry and physics figures are deterministic;
Decision Time is wall clock on this machine.

    python bench/bench_physics_baselines.py [--groups 5] [--datasets repetitive,diverse,longboard]
                                            [--policies dbl,hm,...]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import Counter
from typing import Any

from _common import machine


def run(dataset: str, policy_name: str, groups: int) -> dict[str, Any]:
    from robobpp.datasets import episode_specs
    from robobpp.episode import run_episode
    from robobpp.policies import load_policy

    results = []
    cpu0 = time.process_time()
    for spec in episode_specs(dataset, split="train", groups=groups):
        results.append(run_episode(spec, load_policy(policy_name), "physics"))
    cpu = time.process_time() - cpu0

    def mean(key: str) -> float:
        values = [r.metrics.get(key) for r in results]
        present = [v for v in values if v is not None]
        return statistics.mean(present) if present else float("nan")

    return {
        "util": mean("space_utilization"),
        "occ": mean("occupancy"),
        "dt_ms": mean("decision_time") * 1000,
        "ls_m": mean("local_stability"),
        "ss": mean("static_stability"),
        "placed": statistics.mean(r.boxes_placed for r in results),
        "ends": Counter(r.termination for r in results),
        "cpu": cpu,
    }


def main() -> None:
    from robobpp.policies import BASELINES

    parser = argparse.ArgumentParser()
    parser.add_argument("--groups", type=int, default=5)
    parser.add_argument("--datasets", default="repetitive,diverse,longboard")
    parser.add_argument("--policies", default=",".join(BASELINES))
    args = parser.parse_args()
    print(f"machine: {machine()}")
    print(
        "| dataset | policy | Space Util. ↑ | Occupancy ↑ | Decision Time (ms) ↓ | Local Stab. (m) ↓ "
        "| Static Stab. ↑ | boxes placed | episodes ended by | CPU s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for dataset in args.datasets.split(","):
        for name in args.policies.split(","):
            r = run(dataset, name, args.groups)
            ends = ", ".join(f"{k} {v}" for k, v in sorted(r["ends"].items()))
            print(
                f"| {dataset} | {name} | {r['util']:.3f} | {r['occ']:.3f} | {r['dt_ms']:.2f} | {r['ls_m']:.4f} "
                f"| {r['ss']:.3f} | {r['placed']:.1f} | {ends} | {r['cpu']:.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
