"""How much the Execution Pack's dangerous operations depend on the planning budget.

The reference calls an operation dangerous when one IK + OMPL planning call runs over 15 s of wall time, which its
RRT only does when it finds no exact path before that (it then runs to its time limit and returns an approximate
path). Ours: no collision-free path within a budget of state-validity checks (``PlannerConfig.max_checks``,
6,000), the deterministic stand-in. If the same operations fail with several times the budget, the rule measures
the scene (no path to be found), not the constant.

Replays the Math Pack plans of the given episodes open loop (the paper protocol) in the Execution Pack, once per
budget, and prints per budget: operations, the planners' outcomes, dangerous operations by reason, the boxes
placed and the mean Space Utilization; then the operations' execution times (the ``slow`` criterion, 3.0 s) and
validity checks per planning call.

    nice python bench/execution_budget.py --dataset diverse --policies br,macs,sdfpack --groups 10 \\
        --budgets 6000,24000
"""

from __future__ import annotations

import argparse
import statistics
from collections import Counter

import numpy as np
import paper_table

from robobpp.reproduction import run_baselines
from robobpp.sim.planner import PlannerConfig


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--dataset", default="diverse")
    parser.add_argument("--policies", default="br,macs,sdfpack")
    parser.add_argument("--groups", type=int, default=10)
    parser.add_argument("--first-group", type=int, default=0)
    parser.add_argument(
        "--budgets", default="6000,24000", help="max_checks values (simplification: a quarter)"
    )
    args = parser.parse_args()
    from robobpp.datasets import episode_specs

    specs = episode_specs(args.dataset, "train", args.first_group + args.groups)[args.first_group :]
    times: list[str] = []
    print("| budget (checks) | operations | plan status | dangerous reasons | boxes placed | Space Util. |")
    print("|---:|---:|---|---|---:|---:|")
    for budget in (int(b) for b in args.budgets.split(",")):
        paper_table.SETTING_OPTIONS["planner"] = PlannerConfig(max_checks=budget, simplify_checks=budget // 4)
        status: Counter[str] = Counter()
        reasons: Counter[str] = Counter()
        placed, utilization, operations, seconds, checks = [], [], 0, [], []
        for policy in args.policies.split(","):
            for (r,) in run_baselines(specs, policy, ["execution"], setting_for=paper_table.make_setting):
                for s in r.steps:
                    if s.extra and "plan_status" in s.extra:
                        status[str(s.extra["plan_status"])] += 1
                        reasons.update(s.extra.get("dangerous_reasons", ()))
                    if s.extra and "execution_time_s" in s.extra:
                        seconds.append(float(s.extra["execution_time_s"]))
                        checks.append(int(s.extra["plan_checks"]))
                operations += r.counters["operations"]
                placed.append(r.boxes_placed)
                util = r.metrics["space_utilization"]
                assert util is not None  # every setting measures it
                utilization.append(util)
        print(
            f"| {budget} | {operations} | {', '.join(f'{k} {v}' for k, v in status.most_common())} "
            f"| {', '.join(f'{k} {v}' for k, v in reasons.most_common()) or '–'} "
            f"| {statistics.mean(placed):.1f} | {statistics.mean(utilization):.3f} |",
            flush=True,
        )

        q = np.percentile
        times.append(
            f"| {budget} | {q(seconds, 50):.2f} / {q(seconds, 95):.2f} / {max(seconds):.2f} "
            f"| {q(checks, 50):.0f} / {q(checks, 95):.0f} / {max(checks)} |"
        )
    print(
        "\n| budget (checks) | execution time p50 / p95 / max (s) | checks per planning call p50 / p95 / max |"
    )
    print("|---:|---|---|")
    print("\n".join(times))


if __name__ == "__main__":
    main()
