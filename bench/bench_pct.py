"""PCT: decision time on one core, and its Space Utilization.

    OPENBLAS_NUM_THREADS=1 python bench/bench_pct.py [--groups 30]

Math Pack, train-split Repetitive groups (PCT's training distribution), one process. Each decision is
``PCT.act`` (tree nodes + forward pass), timed by thread CPU time and wall clock. The support model of a
state (robobpp/core/feasibility.py, cached per state for every policy) is part of the decision; its build
is also shown alone. One core:
numpy's BLAS threads are limited to one by the variable above (set before numpy loads). Markdown to stdout.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

from _common import machine, median, percentile

from robobpp.datasets import episode_specs
from robobpp.episode import Episode
from robobpp.policies import load_policy
from robobpp.policies.candidates import support_model


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--groups", type=int, default=30)
    parser.add_argument("--dataset", default="repetitive")
    args = parser.parse_args()
    specs = episode_specs(args.dataset, split="train", groups=args.groups, seed=0)
    cpu: list[float] = []
    wall: list[float] = []
    build: list[float] = []
    utils: list[float] = []
    for k, spec in enumerate(specs, 1):
        policy = load_policy("pct")
        episode = Episode(spec, "math")
        policy.reset(episode.info)
        while not episode.done:
            obs = episode.observe()
            c0, w0 = time.thread_time(), time.perf_counter()
            support_model(obs)  # built once per state (cached), shared with Math Pack's own check
            c1 = time.thread_time()
            action = policy.act(obs)
            cpu.append(time.thread_time() - c0)
            wall.append(time.perf_counter() - w0)
            build.append(c1 - c0)
            episode.step(action, wall[-1])
        util = episode.result("pct").metrics["space_utilization"]
        assert util is not None  # every setting measures it
        utils.append(util)
        print(f"\r{k}/{len(specs)}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    ms = [1000 * t for t in cpu]
    wall_ms = [1000 * t for t in wall]
    print(f"Machine: {machine()}; {args.dataset}, {args.groups} train groups\n")
    build_ms = [1000 * t for t in build]
    print(
        "| decisions | CPU median (ms) | CPU p95 (ms) | of which support model, median (ms) | wall median (ms) "
        "| wall p95 (ms) | Space Utilization |"
    )
    print("|---|---|---|---|---|---|---|")
    print(
        f"| {len(ms)} | {median(ms):.2f} | {percentile(ms, 95):.2f} | {median(build_ms):.2f} | "
        f"{median(wall_ms):.2f} | {percentile(wall_ms, 95):.2f} | {statistics.mean(utils):.3f} |"
    )


if __name__ == "__main__":
    main()
