"""Fidelity of the default physics (fast mode) against the full dynamic simulation on REAL train groups, and
the full simulation against itself (docs/validation/physics.md, "Fidelity"). Too slow for CI; CI runs a handful of
these episodes (tests/sim/physics/test_fidelity_real.py).

    python bench/fidelity_physics.py --groups 10 --policies dbl,hm,lsah --out fidelity.jsonl
    python bench/fidelity_physics.py --summarize fidelity.jsonl

Per episode three runs: ``fast`` (the default), ``full`` (every box dynamic, the whole 200-step window at
every placement) and ``full+0.1mm`` (full with each landing started 0.1 mm higher: the reference's own chaos).
Two runs *agree* on an episode when they end for the same reason, place the same number of boxes (±1) and
their Local Stability is within 5 mm. The pass mark: fast agrees with full as often as full+0.1mm does,
tested with the exact one-sided McNemar test on the paired outcomes (are there significantly more episodes
where only the fast comparison disagrees than where only the noise comparison does?).

Each episode's line (JSON) also holds the CPU seconds of every box (observe + decision + place and settle),
so the same run gives the per-dataset CPU-s per box of the default mode beside the full simulation's.
Episodes run group by group across datasets and policies, so a run cut short still covers all of them.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

from _common import CpuPerStep, machine, median, percentile

from robobpp.datasets import DATASETS, episode_specs
from robobpp.episode import EpisodeResult, run_episode
from robobpp.policies import load_policy
from robobpp.sim.physics import PhysicsConfig, PhysicsPack
from robobpp.sim.physics.fidelity import Outcome, compare, mcnemar_one_sided

RUNS: dict[str, dict[str, Any]] = {
    "fast": {"mode": "fast"},
    "full": {"mode": "full"},
    "full+0.1mm": {"mode": "full", "lower_from_cm": PhysicsConfig().lower_from_cm + 0.01},
}


def outcome(run: dict[str, Any]) -> Outcome:
    return Outcome(run["termination"], run["placed"], run["ls"] or 0.0)


def run_one(spec: Any, policy: str, run: str) -> dict[str, Any]:
    clock = CpuPerStep()
    result: EpisodeResult = run_episode(spec, load_policy(policy), PhysicsPack(**RUNS[run]), on_step=clock)
    return {
        "termination": result.termination,
        "placed": result.boxes_placed,
        "ls": result.metrics.get("local_stability"),
        "util": result.metrics.get("space_utilization"),
        "static": result.metrics.get("static_stability"),
        "cpu_per_box": clock.per_box,
    }


def summarize(lines: list[dict[str, Any]]) -> str:
    out = []
    by_ds: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for line in lines:
        by_ds[line["dataset"]].append(line)
    out.append(
        "| dataset | episodes | compared | same termination | boxes placed ±1 | LS within 5 mm | agree (all three) |"
    )
    out.append("|---|---|---|---|---|---|---|")
    pairs = {"fast vs full": ("fast", "full"), "full+0.1mm vs full": ("full+0.1mm", "full")}
    flags: dict[str, list[bool]] = {name: [] for name in pairs}
    for ds in [*by_ds, "all"]:
        rows = lines if ds == "all" else by_ds[ds]
        for name, (a, b) in pairs.items():
            got = [compare(outcome(r["runs"][a]), outcome(r["runs"][b])) for r in rows]
            n = len(got)
            cols = [
                sum(g.same_termination for g in got),
                sum(g.same_boxes for g in got),
                sum(g.same_local_stability for g in got),
            ]
            both = sum(g.agree for g in got)
            if ds == "all":
                flags[name] = [g.agree for g in got]
            out.append(
                f"| {ds} | {n} | {name} | {cols[0]}/{n} | {cols[1]}/{n} | {cols[2]}/{n} | {both}/{n} |"
            )
    fast_only = sum(
        f and not n for f, n in zip(flags["full+0.1mm vs full"], flags["fast vs full"], strict=True)
    )
    noise_only = sum(
        n and not f for f, n in zip(flags["full+0.1mm vs full"], flags["fast vs full"], strict=True)
    )
    # Discordant pairs: b = only fast disagrees, c = only the noise run disagrees. H0: b and c are equally
    # likely; H1: fast disagrees more often (one-sided exact McNemar = binomial test on b of b + c).
    p_value = mcnemar_one_sided(fast_only, noise_only)
    out.append("")
    out.append(
        f"discordant episodes: only fast vs full disagrees {fast_only}, only full+0.1mm vs full "
        f"disagrees {noise_only}; exact one-sided McNemar p = {p_value:.3f} "
        f"({'pass' if p_value >= 0.05 else 'FAIL'} at 0.05)"
    )
    out.append("")
    out.append("| dataset | boxes | fast CPU-s/box median | fast p95 | full CPU-s/box median | full p95 |")
    out.append("|---|---|---|---|---|---|")
    for ds, rows in by_ds.items():
        fast = [c for r in rows for c in r["runs"]["fast"]["cpu_per_box"]]
        full = [c for r in rows for c in r["runs"]["full"]["cpu_per_box"]]
        out.append(
            f"| {ds} | {len(fast)} / {len(full)} | {median(fast):.4f} | {percentile(fast, 95):.4f} "
            f"| {median(full):.4f} | {percentile(full, 95):.4f} |"
        )
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--groups", type=int, default=10)
    parser.add_argument("--first-group", type=int, default=0)
    parser.add_argument("--policies", default="dbl,hm,lsah")
    parser.add_argument("--datasets", default=",".join(DATASETS))
    parser.add_argument("--out", type=Path, default=Path("fidelity.jsonl"))
    parser.add_argument(
        "--summarize", type=Path, nargs="+", help="only print the tables of existing --out files (together)"
    )
    args = parser.parse_args()
    if args.summarize:
        texts = [t for path in args.summarize for t in path.read_text().splitlines()]
        print(summarize([json.loads(t) for t in texts if t.strip()]))
        return
    print(f"machine: {machine()}", flush=True)
    datasets = args.datasets.split(",")
    specs = {ds: episode_specs(ds, groups=args.first_group + args.groups) for ds in datasets}
    lines = []
    with args.out.open("a") as fh:
        for g in range(args.first_group, args.first_group + args.groups):
            for ds in datasets:
                for policy in args.policies.split(","):
                    spec = specs[ds][g]
                    runs = {run: run_one(spec, policy, run) for run in RUNS}
                    line = {"dataset": ds, "policy": policy, "group": spec.group, "runs": runs}
                    fh.write(json.dumps(line) + "\n")
                    fh.flush()
                    lines.append(line)
                    brief = " / ".join(
                        f"{r['termination']} {r['placed']} {(r['ls'] or 0) * 1000:.1f}mm"
                        for r in runs.values()
                    )
                    print(
                        f"# {ds} {policy} group {spec.group}: fast / full / full+0.1mm = {brief}", flush=True
                    )
    print(summarize(lines))


if __name__ == "__main__":
    main()
