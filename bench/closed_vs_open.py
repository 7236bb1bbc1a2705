"""Closed loop against the paper's protocol in the Physics Pack, per policy and dataset.

For each dataset and policy, on the first ``--groups`` train groups (seed 0, from ``--first-group``): the policy's
Math Pack episode; that episode replayed open loop in the Physics Pack (the paper's protocol,
``robobpp.replay.run_paper_loop``: plan on ideal geometry, replay blind); and the policy run closed loop in the
Physics Pack (it observes the pile after every placement). The table sets the three mean Space Utilizations side by
side with the target "closed ≥ paper protocol − 0.03", and how the episodes ended.

    nice python bench/closed_vs_open.py --groups 30 --datasets longboard --json cl_longboard.json
    nice python bench/closed_vs_open.py --groups 15 --first-group 15 --datasets diverse --json cl_diverse_15.json
    python bench/closed_vs_open.py --merge cl_*.json [--explain]   # one table from earlier runs (episodes pooled)

``--pct-no-support`` (experiment) runs PCT with no support rule in its leaves, in the physical settings too (the
reference's PCT checks its leaves there; the paper's heuristics never do).

``--explain`` also lists, for each cell that misses the target, the episodes where the closed loop fell furthest
below the replay: boxes placed and how each ended. ``--tilt DEG`` counts the boxes still in place at the end whose
attitude is more than DEG degrees off how they were placed (they count as in place, as in the reference: its
collapse rule reads the horizontal displacement only).

Geometry and physics figures are deterministic; only the CPU seconds depend on the machine.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from collections import Counter
from typing import Any

from _common import machine

from robobpp.vocabulary import DATASETS

#: The paper's seven heuristics, in its order, and PCT.
POLICIES = ("dbl", "hm", "lsah", "onlinebph", "br", "macs", "sdfpack", "pct")
#: The target: the closed loop may fall this far below the paper protocol, no further.
SLACK = 0.03
#: Boxes tilted more than this many degrees count as tilted in ``tilted_in_place``.
TILT_DEG = 10.0


def tilt_deg(quaternion: list[float] | None) -> float:
    """How far (degrees) an attitude is turned from how the box was placed, about any axis."""
    if quaternion is None:
        return 0.0
    return math.degrees(2 * math.acos(min(1.0, abs(float(quaternion[3])))))


def record(r: Any, tilt: float) -> dict[str, Any]:
    """One episode's figures: utilisation, boxes, how it ended, and the in-place boxes that are tilted."""
    tilted = [f for f in r.final if f["in_place"] and tilt_deg(f["actual"].get("quaternion")) > tilt]
    volume = r.container["length"] * r.container["width"] * r.container["height"]
    return {
        "space_utilization": r.metrics["space_utilization"],
        "boxes_placed": r.boxes_placed,
        "termination": r.termination,
        "termination_detail": r.termination_detail,
        "tilted_in_place": len(tilted),
        "tilted_volume": sum(
            f["planned"]["length"] * f["planned"]["width"] * f["planned"]["height"] for f in tilted
        )
        / volume,
    }


def run_cell(
    dataset: str, policy: str, groups: int, first_group: int, tilt: float, protocols: set[str]
) -> dict[str, Any]:
    """The Math episode of every group, and the Physics episodes of ``protocols`` (``paper``, ``closed``)."""
    from robobpp.datasets import episode_specs
    from robobpp.episode import run_episode
    from robobpp.policies import load_policy
    from robobpp.replay import replay_math_result

    cpu0 = time.process_time()
    episodes = []
    # A group's boxes depend on its index only, so groups first_group.. are the same as in a longer run.
    for spec in episode_specs(dataset, "train", first_group + groups)[first_group:]:
        math_result = run_episode(spec, load_policy(policy), "math")
        episode = {"group": spec.group, "math": record(math_result, tilt)}
        if "paper" in protocols:
            episode["paper"] = record(replay_math_result(math_result, spec, "physics"), tilt)
        if "closed" in protocols:
            episode["closed"] = record(run_episode(spec, load_policy(policy), "physics"), tilt)
        episodes.append(episode)
    return {"episodes": episodes, "cpu_s": time.process_time() - cpu0}


def mean(episodes: list[dict[str, Any]], protocol: str, key: str = "space_utilization") -> float:
    """The mean figure over the episodes that ran ``protocol`` (NaN when none did)."""
    values = [e[protocol][key] for e in episodes if protocol in e]
    return statistics.mean(values) if values else float("nan")


def endings(episodes: list[dict[str, Any]], protocol: str) -> str:
    from robobpp.export import endings as ending_counts  # the exports' labels: "collapse 27, no place 2"

    return ending_counts(Counter(e[protocol]["termination"] for e in episodes if protocol in e))


def print_table(cells: dict[str, dict[str, dict[str, Any]]]) -> None:
    print(
        "| dataset | policy | groups | Math | paper protocol | closed loop | closed − paper | ≥ paper − 0.03 "
        "| boxes Math / paper / closed | paper endings | closed endings | tilted in place (closed) |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---|---|---|---|---:|")
    for dataset, figures in cells.items():
        for policy, cell in figures.items():
            eps = cell["episodes"]
            m, p, c = (mean(eps, k) for k in ("math", "paper", "closed"))
            boxes = " / ".join(f"{mean(eps, k, 'boxes_placed'):.1f}" for k in ("math", "paper", "closed"))
            tilted = sum(e["closed"]["tilted_in_place"] for e in eps if "closed" in e)
            share = mean(eps, "closed", "tilted_volume")
            print(
                f"| {dataset} | {policy} | {len(eps)} | {m:.3f} | {p:.3f} | {c:.3f} | {c - p:+.3f} "
                f"| {'–' if math.isnan(p - c) else 'yes' if c >= p - SLACK else '**no**'} | {boxes} "
                f"| {endings(eps, 'paper')} "
                f"| {endings(eps, 'closed')} | {tilted} ({share:.3f}) |"
            )
    agreement(cells)
    dbl = cells.get("longboard", {}).get("dbl")
    if dbl:
        m, c = mean(dbl["episodes"], "math"), mean(dbl["episodes"], "closed")
        verdict = "met" if c >= 0.8 * m else "missed"
        print(
            f"\nLong Board DBL: closed loop {c:.3f} vs Math {m:.3f}: {c / m:.2f} × Math (target ≥ 0.8: {verdict})"
        )


def agreement(cells: dict[str, dict[str, dict[str, Any]]]) -> None:
    """Per dataset and protocol: Spearman and mean |diff| against the paper's Physics Pack figures."""
    from robobpp.paper import paper_tables
    from robobpp.reproduction import spearman

    tables = paper_tables()
    print("\n| dataset | protocol | policies | Spearman with the paper | mean abs diff |")
    print("|---|---|---:|---:|---:|")
    for dataset, figures in cells.items():
        for protocol in ("paper", "closed"):
            pairs = []
            for policy, cell in figures.items():
                theirs = tables.get("physics", dataset, policy, "space_utilization")
                ours = mean(cell["episodes"], protocol)
                if theirs is not None and not math.isnan(ours):
                    pairs.append((ours, theirs.value))
            if len(pairs) >= 3:
                rho = spearman([o for o, _ in pairs], [t for _, t in pairs])
                diff = statistics.mean(abs(o - t) for o, t in pairs)
                print(
                    f"| {dataset} | {protocol} | {len(pairs)} | {rho if rho is None else f'{rho:.2f}'} | {diff:.3f} |"
                )


def explain(cells: dict[str, dict[str, dict[str, Any]]], worst: int) -> None:
    """The episodes behind each missed target: where the closed loop fell furthest below the replay."""
    for dataset, figures in cells.items():
        for policy, cell in figures.items():
            eps = cell["episodes"]
            eps = [e for e in eps if "closed" in e and "paper" in e]
            if not eps or mean(eps, "closed") >= mean(eps, "paper") - SLACK:
                continue
            print(
                f"\n{dataset} {policy}: the {worst} episodes where closed loop is furthest below the replay"
            )
            gap = sorted(
                eps, key=lambda e: e["closed"]["space_utilization"] - e["paper"]["space_utilization"]
            )
            for e in gap[:worst]:
                p, c = e["paper"], e["closed"]
                print(
                    f"  group {e['group']}: paper {p['space_utilization']:.3f} ({p['boxes_placed']} boxes, "
                    f"{p['termination']}) vs closed {c['space_utilization']:.3f} ({c['boxes_placed']} boxes, "
                    f"{c['termination']}: {c['termination_detail']})"
                )
            below = sum(e["closed"]["space_utilization"] < e["paper"]["space_utilization"] for e in eps)
            print(f"  closed below paper in {below} of {len(eps)} episodes")


def pct_without_support() -> None:
    """Experiment only: PCT's leaves as in Math Pack (no support rule) in every setting."""
    import robobpp.policies.candidates as candidates
    import robobpp.policies.pct.leaves as leaves

    vars(leaves)["support_model"] = lambda obs: candidates._NO_RULE  # a name leaves imported, not exports


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--groups", type=int, default=30)
    parser.add_argument("--first-group", type=int, default=0)
    parser.add_argument("--datasets", default=",".join(DATASETS))
    parser.add_argument("--policies", default=",".join(POLICIES))
    parser.add_argument("--json", help="write every episode's figures here (as it goes)")
    parser.add_argument(
        "--merge", nargs="+", metavar="JSON", help="one table from earlier runs' --json files"
    )
    parser.add_argument("--explain", action="store_true", help="list the episodes behind each missed target")
    parser.add_argument("--tilt", type=float, default=TILT_DEG, help="degrees a box must be tilted to count")
    parser.add_argument(
        "--protocols", default="paper,closed", help="the Physics runs besides Math: paper, closed"
    )
    parser.add_argument("--pct-no-support", action="store_true", help="experiment: PCT's leaves unchecked")
    args = parser.parse_args()
    if args.pct_no_support:
        pct_without_support()
    cells: dict[str, dict[str, dict[str, Any]]] = {}
    for path in args.merge or ():
        with open(path) as fh:
            for dataset, figures in json.load(fh)["cells"].items():
                for policy, cell in figures.items():
                    mine = cells.setdefault(dataset, {}).setdefault(policy, {"episodes": [], "cpu_s": 0.0})
                    by_group = {e["group"]: e for e in mine["episodes"]}
                    for e in cell["episodes"]:  # runs of other protocols on the same groups join the episode
                        known = by_group.setdefault(e["group"], {"group": e["group"]})
                        if (set(known) & set(e)) - {"group", "math"}:
                            sys.exit(f"{path}: {dataset}/{policy} group {e['group']} again")
                        if "math" in known and known["math"] != e["math"]:
                            sys.exit(f"{path}: {dataset}/{policy} group {e['group']}: another Math episode")
                        known.update(e)
                    mine["episodes"] = sorted(by_group.values(), key=lambda e: e["group"])
                    mine["cpu_s"] += cell["cpu_s"]
    if not args.merge:
        for dataset in (d for d in args.datasets.split(",") if d):
            for policy in (p for p in args.policies.split(",") if p):
                protocols = set(args.protocols.split(","))
                cell = run_cell(dataset, policy, args.groups, args.first_group, args.tilt, protocols)
                cells.setdefault(dataset, {})[policy] = cell
                eps = cell["episodes"]
                print(
                    f"# {dataset} {policy}: math {mean(eps, 'math'):.3f} paper {mean(eps, 'paper'):.3f} "
                    f"closed {mean(eps, 'closed'):.3f} ({cell['cpu_s']:.0f} CPU-s)",
                    flush=True,
                )
                if args.json:
                    with open(args.json, "w") as fh:
                        json.dump({"tilt_deg": args.tilt, "cells": cells}, fh, indent=1)
    cpu = sum(c["cpu_s"] for f in cells.values() for c in f.values())
    print(f"\nPhysics Pack, train split (seed 0), Space Utilization; {cpu:.0f} CPU-s. {machine()}\n")
    print_table(cells)
    if args.explain:
        explain(cells, 5)


if __name__ == "__main__":
    main()
