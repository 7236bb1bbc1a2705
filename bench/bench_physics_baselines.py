"""Physics Pack (or Execution Pack) figures of every baseline policy (``robobpp.policies.BASELINES``) on the
train split, beside the paper's, with the Spearman rank correlation of Space Utilization per dataset.

For each dataset, the first ``--groups`` train groups (80 boxes each) are run with every baseline through
the one episode loop (``run_episode``, which measures Decision Time itself) in the default setting, and the
per-episode metrics are averaged: Space Utilization, Occupancy, Decision Time, Local Stability, Static
Stability, boxes placed, and how the episodes ended. Geometry and physics figures are deterministic;
Decision Time is wall clock on this machine. The paper's figures (its appendix tables, test split, the
authors' simulator) exist for the seven heuristics DBL, LSAH, HM, SDFPack, OnlineBPH, MACS and BR; the
Spearman correlation is over those present in the run.

    python bench/bench_physics_baselines.py [--groups 10] [--setting physics|execution]
                                            [--datasets repetitive,diverse,longboard] [--policies dbl,hm,...]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import Counter
from typing import Any

import numpy as np
from _common import machine

#: Space Utilization in the paper's appendix tables (Physics Pack / Execution Pack), per dataset.
PAPER_UTILIZATION: dict[str, dict[str, dict[str, float]]] = {
    "physics": {
        "repetitive": {"hm": 0.398, "dbl": 0.385, "lsah": 0.373, "br": 0.222, "sdfpack": 0.150,
                       "onlinebph": 0.116, "macs": 0.070},
        "diverse": {"hm": 0.330, "lsah": 0.285, "sdfpack": 0.259, "br": 0.258, "dbl": 0.257, "macs": 0.134,
                    "onlinebph": 0.120},
        "longboard": {"dbl": 0.349, "onlinebph": 0.277, "hm": 0.255, "lsah": 0.254, "br": 0.169,
                      "sdfpack": 0.155, "macs": 0.135},
    },
    "execution": {
        "repetitive": {"dbl": 0.359, "lsah": 0.304, "br": 0.121, "onlinebph": 0.118, "sdfpack": 0.098,
                       "hm": 0.083, "macs": 0.047},
        "diverse": {"dbl": 0.183, "hm": 0.143, "macs": 0.125, "sdfpack": 0.100, "onlinebph": 0.097,
                    "lsah": 0.091, "br": 0.067},
        "longboard": {"dbl": 0.285, "onlinebph": 0.240, "hm": 0.214, "lsah": 0.187, "br": 0.124,
                      "macs": 0.123, "sdfpack": 0.119},
    },
}  # fmt: skip


def _ranks(values: list[float]) -> np.ndarray:
    """Ranks 1..n, ties sharing their mean rank."""
    v = np.asarray(values, dtype=float)
    order = np.argsort(v, kind="stable")
    ranks = np.empty(len(v))
    ranks[order] = np.arange(1, len(v) + 1)
    for value in np.unique(v):
        tied = v == value
        ranks[tied] = ranks[tied].mean()
    return ranks


def spearman(a: list[float], b: list[float]) -> float:
    """Spearman's rank correlation: Pearson's correlation of the ranks (ties at mean rank)."""
    if len(a) != len(b) or len(a) < 3:
        return float("nan")
    return float(np.corrcoef(_ranks(a), _ranks(b))[0, 1])


def run(dataset: str, policy_name: str, groups: int, setting: str) -> dict[str, Any]:
    from robobpp.datasets import episode_specs
    from robobpp.episode import run_episode
    from robobpp.policies import load_policy

    results = []
    cpu0 = time.process_time()
    for spec in episode_specs(dataset, split="train", groups=groups):
        results.append(run_episode(spec, load_policy(policy_name), setting))
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
    parser.add_argument("--groups", type=int, default=10)
    parser.add_argument("--setting", choices=("physics", "execution"), default="physics")
    parser.add_argument("--datasets", default="repetitive,diverse,longboard")
    parser.add_argument("--policies", default=",".join(BASELINES))
    args = parser.parse_args()
    print(f"machine: {machine()}; {args.setting} pack, {args.groups} train groups per dataset")
    print("| dataset | policy | Space Util. ↑ | paper | Occupancy ↑ | Decision Time (ms) ↓ | Local Stab. (m) ↓ "
          "| Static Stab. ↑ | boxes placed | episodes ended by | CPU s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    correlations = []
    for dataset in args.datasets.split(","):
        paper = PAPER_UTILIZATION[args.setting][dataset]
        ours: dict[str, float] = {}
        for name in args.policies.split(","):
            r = run(dataset, name, args.groups, args.setting)
            ours[name] = r["util"]
            ends = ", ".join(f"{k} {v}" for k, v in sorted(r["ends"].items()))
            theirs = f"{paper[name]:.3f}" if name in paper else "–"
            print(
                f"| {dataset} | {name} | {r['util']:.3f} | {theirs} | {r['occ']:.3f} | {r['dt_ms']:.2f} "
                f"| {r['ls_m']:.4f} | {r['ss']:.3f} | {r['placed']:.1f} | {ends} | {r['cpu']:.0f} |",
                flush=True,
            )
        both = [n for n in ours if n in paper]
        rho = spearman([ours[n] for n in both], [paper[n] for n in both])
        gap = float(np.mean([abs(ours[n] - paper[n]) for n in both])) if both else float("nan")
        correlations.append(
            f"{dataset}: Spearman {rho:+.2f} over {len(both)} heuristics, mean |diff| {gap:.3f}"
        )
    print("\n".join(correlations))


if __name__ == "__main__":
    main()
