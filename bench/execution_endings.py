"""Execution Pack endings against the reference: what each of its ending rules would do to a run's figures.

Reads the ``--json`` files of ``paper_table.py --setting execution`` runs (pooled like ``--merge``) and prints, per
dataset and heuristic, the mean Space Utilization as run and as it would be had the episode ended where the
reference ends it, counted from the recorded operations (no re-simulation):

* *failed place*: at the first operation whose place plan could not start (``unreachable``,
  ``no_path:goal_invalid``, ``no_path:start_invalid``), the box not placed (packsim's "Move_ee_to fail");
* *3rd dangerous*: at the third operation that was dangerous by the robot's motion (a failed grasp alone does
  not count), that box not counted (packsim's ``dangerous_num > 2``);
* *both*: whichever comes first.

An episode cut at step k keeps the volume of boxes 0 … k−1: none of them had collapsed by then, since a
collapse ends the episode. The figures beside the paper's with Spearman and mean |diff| per dataset; then the
operations' dangerous reasons, how episodes ended, and how many collapses followed a dangerous operation.

    python bench/execution_endings.py run1.json [run2.json ...]
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from typing import Any

import numpy as np
from paper_table import POLICIES, paper_figures

from robobpp.reproduction import spearman
from robobpp.sim.execution.pack import PLACE_FAILURES
from robobpp.vocabulary import DATASETS


def load(paths: list[str]) -> dict[str, dict[str, list[dict[str, Any]]]]:
    """Episodes per dataset and heuristic, pooled over the files (a group only once)."""
    out: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for path in paths:
        with open(path) as fh:
            run = json.load(fh)
        if run["setting"] != "execution":
            raise SystemExit(f"{path}: a {run['setting']} run, not execution")
        for dataset, cells in run["ours"].items():
            for policy, cell in cells.items():
                have = out.setdefault(dataset, {}).setdefault(policy, [])
                seen = {e["group"] for e in have}
                have.extend(e for e in cell["episodes"] if e["group"] not in seen)
    return out


def cut_utilization(episode: dict[str, Any], volumes: list[float], capacity: float, rule: str) -> float:
    """The episode's utilization had it ended where ``rule`` ends it (its own figure if it never fires)."""
    motion = 0
    for step, reasons, _woken, _collapsed in episode.get("marked_steps", []):
        failed = any(r in PLACE_FAILURES for r in reasons)
        motion += any(r != "failed_grasp" for r in reasons)
        if (rule in ("place", "both") and failed) or (rule in ("dangerous", "both") and motion >= 3):
            return sum(volumes[:step]) / capacity
    utilisation: float = episode["space_utilization"]
    return utilisation


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("json", nargs="+")
    args = parser.parse_args()
    from robobpp.datasets import episode_specs

    runs = load(args.json)
    rules = {"as run": "", "failed place": "place", "3rd dangerous": "dangerous", "both": "both"}
    table: dict[str, dict[str, dict[str, float]]] = {}
    played: list[str] = [d for d in DATASETS if d in runs]  # the loop variable is reused for the table's keys
    for dataset in played:
        groups = max(e["group"] for cell in runs[dataset].values() for e in cell) + 1
        specs = episode_specs(dataset, "train", groups)
        for policy in [q for q in POLICIES if q in runs[dataset]]:
            episodes = runs[dataset][policy]
            figures = {}
            for name, rule in rules.items():
                values = []
                for e in episodes:
                    spec = specs[e["group"]]
                    volumes = [b.length * b.width * b.height for b in spec.boxes]
                    capacity = spec.container.length * spec.container.width * spec.container.height
                    values.append(
                        cut_utilization(e, volumes, capacity, rule) if rule else e["space_utilization"]
                    )
                figures[name] = float(np.mean(values))
            table.setdefault(dataset, {})[policy] = figures
    published = paper_figures("execution")
    for dataset, cells in table.items():
        policies = list(cells)
        paper = [published[dataset][q] for q in policies]
        print(
            f"\n{dataset} ({len(runs[dataset][policies[0]])} groups): Space Utilization, paper vs ours as run and cut"
        )
        print("| heuristic | paper | " + " | ".join(rules) + " |")
        print("|---|---:|" + "---:|" * len(rules))
        for q, p in zip(policies, paper, strict=True):
            print(f"| {q} | {p:.3f} | " + " | ".join(f"{cells[q][r]:.3f}" for r in rules) + " |")
        rho = [spearman(paper, [cells[q][r] for q in policies]) for r in rules]
        diff = [float(np.mean(np.abs(np.subtract([cells[q][r] for q in policies], paper)))) for r in rules]
        print("| **Spearman** | | " + " | ".join("–" if v is None else f"{v:.2f}" for v in rho) + " |")
        print("| **mean abs diff** | | " + " | ".join(f"{v:.3f}" for v in diff) + " |")
    print(
        "\n| dataset | heuristic | endings | dangerous reasons | collapses after a dangerous op / collapses |"
    )
    print("|---|---|---|---|---:|")
    for dataset in table:
        for policy in table[dataset]:
            episodes = runs[dataset][policy]
            endings = Counter(e["termination"] for e in episodes)
            reasons: Counter[str] = Counter()
            for e in episodes:
                reasons.update(e.get("dangerous_reasons", {}))
            collapses = [m for e in episodes for m in e.get("marked_steps", []) if m[3]]
            print(
                f"| {dataset} | {policy} | {', '.join(f'{k} {v}' for k, v in sorted(endings.items()))} "
                f"| {', '.join(f'{k} {v}' for k, v in reasons.most_common()) or '–'} "
                f"| {sum(1 for m in collapses if m[1])} / {len(collapses)} |"
            )


if __name__ == "__main__":
    main()
