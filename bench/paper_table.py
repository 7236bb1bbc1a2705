"""The paper's baseline table, reproduced: Space Utilization of every paper heuristic × dataset, paper vs ours.

For each dataset the first ``--groups`` train groups (80 boxes each, seed 0) are run with each of the paper's
seven heuristics through the one episode loop (``run_episode``) in ``--setting`` (math, physics or execution).
The mean Space Utilization is set beside the paper's figure (its appendix tables, one per pack), with the
Spearman rank correlation of the seven heuristics and the mean absolute difference per dataset.

    python bench/paper_table.py --setting math --groups 30 [--json out.json] [--datasets ...] [--policies ...]
    nice python bench/paper_table.py --setting physics --groups 10
    python bench/paper_table.py --setting math --support      # experiment: Math Pack with the support rule
    nice python bench/paper_table.py --setting physics --groups 10 --no-support   # experiment: candidates unchecked
    nice python bench/paper_table.py --setting physics --groups 10 --open-loop    # experiment: packsim's replay
    python bench/paper_table.py --merge a.json b.json         # one table from earlier runs' --json files

Geometry and physics figures are deterministic; nothing here depends on the machine but the run time.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections import Counter
from functools import lru_cache
from typing import Any

import numpy as np
from _common import machine

DATASETS = ("repetitive", "diverse", "longboard")
#: The paper's seven heuristics, in its order.
POLICIES = ("dbl", "hm", "lsah", "onlinebph", "br", "macs", "sdfpack")

#: Space Utilization from the paper's appendix tables (test split, 30 sequences): Repetitive, Diverse, Long Board.
PAPER: dict[str, dict[str, tuple[float, float, float]]] = {
    "math": {
        "dbl": (0.617, 0.549, 0.520),
        "hm": (0.579, 0.423, 0.355),
        "lsah": (0.619, 0.569, 0.474),
        "onlinebph": (0.500, 0.474, 0.428),
        "br": (0.587, 0.524, 0.363),
        "macs": (0.445, 0.352, 0.232),
        "sdfpack": (0.586, 0.543, 0.274),
    },
    "physics": {
        "dbl": (0.385, 0.257, 0.349),
        "hm": (0.398, 0.330, 0.255),
        "lsah": (0.373, 0.285, 0.254),
        "onlinebph": (0.116, 0.120, 0.277),
        "br": (0.222, 0.258, 0.169),
        "macs": (0.070, 0.134, 0.135),
        "sdfpack": (0.150, 0.259, 0.155),
    },
    "execution": {
        "dbl": (0.359, 0.183, 0.285),
        "hm": (0.083, 0.143, 0.214),
        "lsah": (0.304, 0.091, 0.187),
        "onlinebph": (0.118, 0.097, 0.240),
        "br": (0.121, 0.067, 0.124),
        "macs": (0.047, 0.125, 0.123),
        "sdfpack": (0.098, 0.100, 0.119),
    },
}


def ranks(values: list[float]) -> np.ndarray:
    """Ranks 1..n, ties given their average rank (as Spearman's rho needs)."""
    a = np.asarray(values, dtype=np.float64)
    order = np.argsort(a, kind="stable")
    out = np.empty(len(a))
    out[order] = np.arange(1, len(a) + 1)
    for v in np.unique(a):
        tied = a == v
        out[tied] = out[tied].mean()
    return out


def spearman(x: list[float], y: list[float]) -> float:
    rx, ry = ranks(x), ranks(y)
    return float(np.corrcoef(rx, ry)[0, 1])


def switch_on_support_in_math() -> None:
    """Experiment only: Math Pack with the reference's support rule, in the setting and in every policy's
    candidates (PCT's own environment does this; packsim's Math Pack does not)."""
    import robobpp.policies.candidates as candidates
    from robobpp.core.feasibility import CONTACT_TOLERANCE_CM, SupportModel, check_support
    from robobpp.sim.base import StepOutcome
    from robobpp.sim.math_pack import MathPack

    candidates._support_model = lru_cache(maxsize=4)(
        lambda placed: SupportModel(placed, CONTACT_TOLERANCE_CM)
    )  # type: ignore[assignment]
    plain_apply = MathPack.apply

    def apply(self: MathPack, box: Any, action: Any, index: int) -> StepOutcome:
        state = self.state()
        planned = state.drop(box, action.x, action.y, action.orientation, index)
        refused = check_support(state.placements, planned)
        return StepOutcome(None, refused) if refused is not None else plain_apply(self, box, action, index)

    MathPack.apply = apply  # type: ignore[method-assign]


def switch_off_support() -> None:
    """Experiment only: no support rule in any policy's candidates, physical settings included."""
    import robobpp.policies.candidates as candidates

    candidates._support_model = lambda placed: candidates._NO_RULE  # type: ignore[assignment]


class Replay:
    """Plays back a fixed list of actions (then says "no feasible placement"): packsim's open loop."""

    name = "replay"

    def __init__(self, actions: list[Any]) -> None:
        self.actions = list(actions)

    def reset(self, info: Any) -> None:
        return None

    def act(self, obs: Any) -> Any:
        return self.actions.pop(0) if self.actions else None

    def close(self, reason: str) -> None:
        return None


def open_loop(spec: Any, policy: str, setting: str) -> Any:
    """Experiment: plan every action in Math Pack, then replay them in ``setting`` — what the reference does
    (packsim replays actions computed offline on idealised geometry; physics never feeds back)."""
    from robobpp.core import Action
    from robobpp.episode import run_episode
    from robobpp.policies import load_policy

    planned = run_episode(spec, load_policy(policy), "math")
    actions = [
        Action(s.action["x"], s.action["y"], s.action["orientation"]) for s in planned.steps if s.action
    ]
    return run_episode(spec, Replay(actions), setting)  # type: ignore[arg-type]


def run(
    dataset: str, policy: str, setting: str, groups: int, split: str = "train", replay: bool = False
) -> dict[str, Any]:
    from robobpp.datasets import episode_specs
    from robobpp.episode import run_episode
    from robobpp.policies import load_policy

    cpu0 = time.process_time()
    specs = episode_specs(dataset, split, groups)
    if replay:
        results = [open_loop(s, policy, setting) for s in specs]
    else:
        results = [run_episode(s, load_policy(policy), setting) for s in specs]
    return {
        "space_utilization": statistics.mean(r.metrics["space_utilization"] for r in results),
        "boxes_placed": statistics.mean(r.boxes_placed for r in results),
        "terminations": dict(Counter(r.termination for r in results)),
        "cpu_s": time.process_time() - cpu0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--setting", choices=("math", "physics", "execution"), default="math")
    parser.add_argument("--groups", type=int, default=30)
    parser.add_argument("--split", choices=("train", "test"), default="train")
    parser.add_argument("--datasets", default=",".join(DATASETS))
    parser.add_argument("--policies", default=",".join(POLICIES))
    parser.add_argument("--json", help="also write every figure here")
    parser.add_argument(
        "--support",
        action="store_true",
        help="experiment: Math Pack with the reference's support rule (setting and every policy's candidates)",
    )
    parser.add_argument(
        "--merge", nargs="+", metavar="JSON", help="print one table from the --json files of earlier runs"
    )
    parser.add_argument(
        "--no-support",
        action="store_true",
        help="experiment: no support rule in the candidates of the physical settings either",
    )
    parser.add_argument(
        "--open-loop",
        action="store_true",
        help="experiment: plan in Math Pack, replay the actions in --setting (packsim's open loop)",
    )
    args = parser.parse_args()
    if args.no_support:
        switch_off_support()
    if args.support:
        switch_on_support_in_math()
    datasets = [d for d in args.datasets.split(",") if d]
    policies = [p for p in args.policies.split(",") if p]
    ours: dict[str, dict[str, dict[str, Any]]] = {}
    for path in args.merge or ():
        with open(path) as fh:
            earlier = json.load(fh)
        # The files say which setting and group count they hold; a table must not mix them, nor compare a
        # Physics run with the paper's Math column because --setting was left at its default.
        if path == args.merge[0]:
            args.setting, args.groups = earlier["setting"], earlier["groups"]
        elif (earlier["setting"], earlier["groups"]) != (args.setting, args.groups):
            parser.error(f"{path} holds {earlier['setting']} / {earlier['groups']} groups, "
                         f"not {args.setting} / {args.groups} groups like {args.merge[0]}")  # fmt: skip
        for dataset, figures in earlier["ours"].items():
            ours.setdefault(dataset, {}).update(figures)
    paper = PAPER[args.setting]
    for dataset in datasets:
        ours.setdefault(dataset, {})
        for policy in policies:
            if policy in ours[dataset]:
                continue
            ours[dataset][policy] = run(
                dataset, policy, args.setting, args.groups, args.split, args.open_loop
            )
            fig = ours[dataset][policy]
            print(f"# {args.setting} {dataset} {policy}: {fig['space_utilization']:.3f} "
                  f"({fig['boxes_placed']:.1f} boxes, {fig['terminations']}, {fig['cpu_s']:.0f} s)", flush=True)  # fmt: skip

    col = {d: DATASETS.index(d) for d in datasets}
    rule = " with the support rule (experiment)" if args.support else ""
    rule = " without the support rule in the candidates (experiment)" if args.no_support else rule
    rule += ", open loop: planned in Math Pack, replayed (experiment)" if args.open_loop else ""
    print(f"\n{args.setting.capitalize()} Pack{rule}, Space Utilization, {args.split} split, {args.groups} groups (seed 0); "
          f"paper: its test-split tables. {machine()}\n")  # fmt: skip
    print("| heuristic | " + " | ".join(f"{d} paper | {d} ours | diff" for d in datasets) + " |")
    print("|---|" + "---:|" * (3 * len(datasets)))
    for policy in policies:
        cells = []
        for d in datasets:
            p, o = paper[policy][col[d]], ours[d][policy]["space_utilization"]
            cells += [f"{p:.3f}", f"{o:.3f}", f"{o - p:+.3f}"]
        print(f"| {policy} | " + " | ".join(cells) + " |")
    summary = {}
    for d in datasets:
        p = [paper[q][col[d]] for q in policies]
        o = [ours[d][q]["space_utilization"] for q in policies]
        summary[d] = {
            "spearman": spearman(p, o) if len(policies) > 2 else float("nan"),
            "mean_abs_diff": float(np.mean(np.abs(np.subtract(o, p)))),
        }
    print("| **Spearman** | " + " | ".join(f" | {summary[d]['spearman']:.2f} | " for d in datasets) + " |")
    print(
        "| **mean abs diff** | "
        + " | ".join(f" | {summary[d]['mean_abs_diff']:.3f} | " for d in datasets)
        + " |"
    )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"setting": args.setting, "groups": args.groups, "ours": ours, "paper": paper,
                       "summary": summary}, fh, indent=1)  # fmt: skip


if __name__ == "__main__":
    main()
