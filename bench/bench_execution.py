"""Execution Pack: seconds per box (planning included) and planning time per placement, DBL, 80-box groups.

One group per dataset (train split, or ``--synthetic`` groups in each dataset's container when offline),
CPU seconds per box of the whole step (observe + DBL + robot operation + settle), planning time median and
p95 per placement, plus the Execution metrics so a speed change that changes outcomes shows.

    python bench/bench_execution.py [--groups 1] [--synthetic] [--datasets repetitive,diverse,longboard]
                                    [--compare-physics]

``--compare-physics`` also runs DBL in the Physics Pack on the same groups and prints the boxes placed per
episode in both settings (the robot should not end episodes much earlier than physics alone does).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import Counter
from typing import Any

from _common import machine, percentile


def _specs(dataset: str, groups: int, synthetic: bool) -> list[Any]:
    if synthetic:
        from robobpp.datasets.synthetic import synthetic_episode_specs

        return synthetic_episode_specs(groups, seed=0, container=dataset)
    from robobpp.datasets import episode_specs

    return episode_specs(dataset, split="train", groups=groups)


def run(dataset: str, groups: int, synthetic: bool) -> dict[str, Any]:
    from robobpp.episode import Episode
    from robobpp.policies import load_policy
    from robobpp.sim.execution import ExecutionPack

    per_box: list[float] = []
    planning: list[float] = []
    statuses: Counter[str] = Counter()
    results = []
    for spec in _specs(dataset, groups, synthetic):
        policy = load_policy("dbl")
        pack = ExecutionPack()
        episode = Episode(spec, pack)
        policy.reset(episode.info)
        while not episode.done:
            t0 = time.process_time()
            action = policy.act(episode.observe())
            episode.step(action, 0.0)
            per_box.append(time.process_time() - t0)
            op = pack.last_operation
            if op is not None:
                planning.append(op.plan_seconds)
                statuses[op.plan_status] += 1
                pack.last_operation = None
        results.append(episode.result("dbl"))
        pack.close()
    metrics = [r.metrics for r in results]
    utilization = [u for m in metrics if (u := m["space_utilization"]) is not None]
    assert len(utilization) == len(metrics)  # every setting measures it
    return {
        "boxes": len(per_box),
        "cpu_per_box": statistics.mean(per_box) if per_box else float("nan"),
        "cpu_median": statistics.median(per_box) if per_box else float("nan"),
        "plan_median": statistics.median(planning) if planning else float("nan"),
        "plan_p95": percentile(planning, 95),
        "statuses": dict(statuses),
        "placed": sum(r.boxes_placed for r in results),
        "placed_each": [r.boxes_placed for r in results],
        "terminations": [r.termination for r in results],
        "traj": statistics.mean(m.get("trajectory_length") or 0.0 for m in metrics),
        "danger": statistics.mean(m.get("dangerous_operation") or 0.0 for m in metrics),
        "util": statistics.mean(utilization),
    }


def physics_placed(dataset: str, groups: int, synthetic: bool) -> list[int]:
    from robobpp.episode import run_episode
    from robobpp.policies import load_policy

    return [
        run_episode(spec, load_policy("dbl"), "physics").boxes_placed
        for spec in _specs(dataset, groups, synthetic)
    ]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--groups", type=int, default=1)
    parser.add_argument("--synthetic", action="store_true")
    parser.add_argument("--datasets", default="repetitive,diverse,longboard")
    parser.add_argument("--compare-physics", action="store_true")
    args = parser.parse_args()
    compare: list[str] = []
    print(f"machine: {machine()}")
    print(
        "| dataset | boxes placed | CPU s/box (mean / median) | vs reference 5.8 | planning p50 / p95 (s) "
        "| plan status | traj. length (m) | dangerous | utilization | termination |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for dataset in args.datasets.split(","):
        r = run(dataset, args.groups, args.synthetic)
        print(
            f"| {dataset} | {r['placed']} | {r['cpu_per_box']:.3f} / {r['cpu_median']:.3f} | "
            f"{5.8 / r['cpu_per_box']:.0f}× faster | {r['plan_median']:.4f} / {r['plan_p95']:.4f} | "
            f"{r['statuses']} | {r['traj']:.2f} | {r['danger']:.3f} | {r['util']:.3f} | "
            f"{', '.join(str(t) for t in r['terminations'])} |",
            flush=True,
        )
        if args.compare_physics:
            physics = physics_placed(dataset, args.groups, args.synthetic)
            execution = r["placed_each"]
            compare.append(
                f"| {dataset} | {statistics.mean(physics):.1f} ({', '.join(map(str, physics))}) | "
                f"{statistics.mean(execution):.1f} ({', '.join(map(str, execution))}) |"
            )
    if compare:
        print("\nDBL boxes placed per episode\n\n| dataset | Physics Pack | Execution Pack |\n|---|---|---|")
        print("\n".join(compare))


if __name__ == "__main__":
    main()
