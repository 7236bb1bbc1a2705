"""Baseline policies: decision time per policy per dataset, and the Math Pack table of all baselines.

    python bench/bench_policies.py time  [--groups 1]    # decision time median / p95 (ms), one core
    python bench/bench_policies.py table [--groups 30]   # Space Utilization, Occupancy, Decision Time

Both run every baseline through the one episode loop (``run_episode``, Math Pack) on train-split groups of
each dataset; decision time is the loop's own wall-clock measurement around ``policy.act``. Progress goes
to stderr, the Markdown table to stdout.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

from _common import machine, median, percentile

from robobpp.core.episode_spec import EpisodeSpec
from robobpp.datasets import DATASETS, episode_specs
from robobpp.episode import Episode, EpisodeResult, run_episode
from robobpp.policies import BASELINES, load_policy

#: Targets of docs/benchmark.md, "Speed targets" (ms per decision).
TARGET_MS = {"macs": 50.0, "sdfpack": 50.0}
DEFAULT_TARGET_MS = 5.0
#: The paper's decision times (s per box), where it reports them, as the reference.
PAPER_S = {"dbl": "0.4–0.7", "hm": "0.3–1.0", "macs": "1–12", "sdfpack": "4–14"}


def run(policy_name: str, specs: list[EpisodeSpec], progress: str) -> list[EpisodeResult]:
    results = []
    for k, spec in enumerate(specs, 1):
        results.append(run_episode(spec, load_policy(policy_name), "math"))
        print(f"\r{progress} {k}/{len(specs)}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return results


def decision_times(
    policy_name: str, specs: list[EpisodeSpec], progress: str
) -> tuple[list[float], list[float]]:
    """Wall and thread-CPU seconds of every ``act`` call over the episodes (Math Pack, step-wise loop).

    CPU time is reported beside wall time because the benchmark machine is shared: wall time there
    includes waiting for a core, thread CPU time does not.
    """
    wall: list[float] = []
    cpu: list[float] = []
    for k, spec in enumerate(specs, 1):
        policy = load_policy(policy_name)
        episode = Episode(spec, "math")
        policy.reset(episode.info)
        while not episode.done:
            obs = episode.observe()
            c0, t0 = time.thread_time(), time.perf_counter()
            action = policy.act(obs)
            t1, c1 = time.perf_counter(), time.thread_time()
            wall.append(t1 - t0)
            cpu.append(c1 - c0)
            episode.step(action, t1 - t0)
        print(f"\r{progress} {k}/{len(specs)}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return wall, cpu


def time_mode(groups: int, policies: list[str]) -> None:
    print(f"machine: {machine()}; Math Pack, {groups} train group(s) of 80 boxes per dataset\n")
    print(
        "| policy | dataset | decisions | CPU median (ms) | CPU p95 (ms) | wall median (ms) | wall p95 (ms) "
        "| target (ms) | paper (s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name in policies:
        for dataset in DATASETS:
            specs = episode_specs(dataset, split="train", groups=groups)
            wall, cpu = decision_times(name, specs, f"{name} {dataset}")
            target = TARGET_MS.get(name, DEFAULT_TARGET_MS)
            print(
                f"| {name} | {dataset} | {len(wall)} | {median(cpu) * 1e3:.2f} | {percentile(cpu, 95) * 1e3:.2f} "
                f"| {median(wall) * 1e3:.2f} | {percentile(wall, 95) * 1e3:.2f} | ≤ {target:g} "
                f"| {PAPER_S.get(name, '–')} |",
                flush=True,
            )


def table_mode(groups: int, policies: list[str]) -> None:
    started = time.perf_counter()
    print(f"machine: {machine()}; Math Pack, train split, {groups} groups of 80 boxes per dataset\n")
    print("| dataset | policy | Space Utilization ↑ | Occupancy ↑ | Decision Time (ms) ↓ | boxes placed |")
    print("|---|---|---|---|---|---|")
    for dataset in DATASETS:
        specs = episode_specs(dataset, split="train", groups=groups)
        for name in policies:
            results = run(name, specs, f"{dataset} {name}")
            util = statistics.mean(r.metrics["space_utilization"] or 0.0 for r in results)
            occ = statistics.mean(r.metrics["occupancy"] or 0.0 for r in results)
            dec = statistics.mean(r.metrics["decision_time"] or 0.0 for r in results)
            placed = statistics.mean(r.boxes_placed for r in results)
            print(
                f"| {dataset} | {name} | {util:.3f} | {occ:.3f} | {dec * 1e3:.2f} | {placed:.1f} |",
                flush=True,
            )
    print(f"\nwall time {time.perf_counter() - started:.0f} s", file=sys.stderr)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("mode", choices=["time", "table"])
    parser.add_argument("--groups", type=int, default=None, help="groups per dataset (time: 1, table: 30)")
    parser.add_argument("--policies", default=",".join(BASELINES), help="comma-separated policy names")
    args = parser.parse_args()
    policies = [p for p in args.policies.split(",") if p]
    if args.mode == "time":
        time_mode(args.groups or 1, policies)
    else:
        table_mode(args.groups or 30, policies)


if __name__ == "__main__":
    main()
