"""PCT: decision time on one core, and Space Utilization with and without the support rule.

    OPENBLAS_NUM_THREADS=1 python bench/bench_pct.py [--groups 30] [--no-support]

Math Pack, train-split Repetitive groups (PCT's training distribution), one process. Each decision is
``PCT.act`` (tree nodes + forward pass), timed by thread CPU time and wall clock. ``--no-support`` drops the
support rule from leaf generation (an ablation: the reference's setting-2 environment has none; Math Pack
then ends an episode at the first unsupported choice). One core:
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
    parser.add_argument("--no-support", action="store_true", help="ablation: leaves without the support rule")
    args = parser.parse_args()
    if args.no_support:
        import types

        import robobpp.policies.pct.leaves as leaves

        anything = types.SimpleNamespace(supports=lambda *_a: True)
        leaves.support_model = lambda _obs: anything  # type: ignore[assignment]
    specs = episode_specs(args.dataset, split="train", groups=args.groups, seed=0)
    cpu, wall, build, utils = [], [], [], []
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
        utils.append(episode.result("pct").metrics["space_utilization"])
        print(f"\r{k}/{len(specs)}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    ms = [1000 * t for t in cpu]
    wall_ms = [1000 * t for t in wall]
    print(f"Machine: {machine()}; {args.dataset}, {args.groups} train groups, support rule "
          f"{'off' if args.no_support else 'on'}\n")  # fmt: skip
    print(
        "| decisions | CPU median (ms) | CPU p95 (ms) | wall median (ms) | wall p95 (ms) | Space Utilization |"
    )
    print("|---|---|---|---|---|---|")
    print(f"| {len(ms)} | {median(ms):.2f} | {percentile(ms, 95):.2f} | {median(wall_ms):.2f} | "
          f"{percentile(wall_ms, 95):.2f} | {statistics.mean(utils):.3f} |")  # fmt: skip


if __name__ == "__main__":
    main()
