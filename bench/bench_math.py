"""Math Pack step time (observe + apply + trace, plus the end-of-episode metrics spread over the boxes) and DBL
decision time, per box, median over one 80-box train group of each dataset, in this single process.

    python bench/bench_math.py [--groups 1]
"""

from __future__ import annotations

import argparse
import time

from _common import machine, median, percentile

from robobpp.datasets import DATASETS, episode_specs
from robobpp.episode import Episode
from robobpp.policies import load_policy


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--groups", type=int, default=1)
    args = parser.parse_args()
    print(f"machine: {machine()}")
    print("| dataset | boxes | step median (ms) | step p95 (ms) | DBL decision median (ms) | DBL p95 (ms) |")
    print("|---|---|---|---|---|---|")
    for name in DATASETS:
        steps: list[float] = []
        decisions: list[float] = []
        boxes = 0
        for spec in episode_specs(name, split="train", groups=args.groups):
            policy = load_policy("dbl")
            episode = Episode(spec, "math")
            per_step: list[float] = []
            while not episode.done:
                t0 = time.perf_counter()
                obs = episode.observe()
                t1 = time.perf_counter()
                action = policy.act(obs)
                t2 = time.perf_counter()
                episode.step(action, t2 - t1)
                t3 = time.perf_counter()
                per_step.append((t1 - t0) + (t3 - t2))
                decisions.append(t2 - t1)
            t4 = time.perf_counter()
            episode.result(policy.name)
            metrics_share = (time.perf_counter() - t4) / max(1, len(per_step))
            steps.extend(s + metrics_share for s in per_step)
            boxes += len(per_step)
        print(
            f"| {name} | {boxes} | {median(steps) * 1e3:.3f} | {percentile(steps, 95) * 1e3:.3f} "
            f"| {median(decisions) * 1e3:.3f} | {percentile(decisions, 95) * 1e3:.3f} |"
        )


if __name__ == "__main__":
    main()
