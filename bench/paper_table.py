"""The paper's baseline table with robobpp's experiment switches: Space Utilization per heuristic × dataset, ours
beside the paper's.

A thin wrapper over the package's reproduction (:mod:`robobpp.reproduction`, the paper's figures in
``robobpp/data/paper_tables.json``): ``robobpp reproduce`` is the product command (the paper protocol, every
metric, PCT too); this script keeps the experiments one switch each, the closed-loop runs (the default here) and
the evidence per heuristic (how its episodes ended, the robot's figures). For each dataset the first ``--groups``
train groups (80 boxes each, seed 0) are run with each heuristic through the one episode loop in ``--setting``;
the mean Space Utilization is set beside the paper's (its appendix tables), with Spearman's rank correlation and
the mean absolute difference per dataset.

    python bench/paper_table.py --setting math --groups 30 [--json out.json] [--datasets ...] [--policies ...]
    nice python bench/paper_table.py --setting physics --groups 10                # closed loop
    nice python bench/paper_table.py --setting physics --groups 10 --open-loop    # the paper protocol (= reproduce)
    python bench/paper_table.py --setting math --support      # experiment: Math Pack with the support rule
    nice python bench/paper_table.py --setting physics --groups 10 --no-support   # experiment: PCT's leaves unchecked
    python bench/paper_table.py --policies sdfpack --sdfpack-step 1   # experiment: SDFPack on the 1 cm grid
    python bench/paper_table.py --policies sdfpack --sdfpack-corner 4.4,0.7,2.4   # experiment: distances from there
    nice python bench/paper_table.py --policies sdfpack --groups 10 --sdfpack-scene   # experiment: true distances
    python bench/paper_table.py --policies onlinebph --onlinebph-item-set   # experiment: the group's item set
    nice python bench/paper_table.py --setting execution --groups 2 --first-group 4 --json e4.json   # groups 4, 5
    python bench/paper_table.py --merge a.json b.json         # one table from earlier runs' --json files (episodes pooled)
    nice python bench/paper_table.py --setting physics --open-loop --groups 5 --physics-option mode=full \
        --physics-option friction_anchor=false --physics-option stability_steps=2200   # experiment: reference-like settle

``--verbose`` (always in Execution Pack) also prints how each heuristic's episodes ended and, in the physical settings,
how often a step moved an earlier box by more than 1 cm; in Execution Pack the dangerous operations, their reasons,
the boxes the robot came near, and how many collapses happened in a dangerous operation.

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

from robobpp.paper import PAPER_HEURISTICS, paper_tables
from robobpp.reproduction import compare, markdown
from robobpp.vocabulary import CLOSED, DATASETS, PAPER, PHYSICAL, SETTINGS

#: The paper's seven heuristics, in its order (``--policies pct`` adds its learned policy).
POLICIES = PAPER_HEURISTICS


def switch_on_support_in_math() -> None:
    """Experiment only: Math Pack with the reference's support rule, in the setting and in every policy's
    candidates (PCT's own environment does this; packsim's Math Pack does not)."""
    import robobpp.policies.candidates as candidates
    from robobpp.core.feasibility import CONTACT_TOLERANCE_CM, SupportModel, check_support
    from robobpp.sim.base import StepOutcome
    from robobpp.sim.math_pack import MathPack

    candidates._support_model = lru_cache(maxsize=4)(
        lambda placed: SupportModel(placed, CONTACT_TOLERANCE_CM)
    )
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


def sdfpack_scene_distances() -> None:
    """Experiment only: SDFPack's distance term as the reference means it, in one unit (cm) — each sample point's
    distance to the nearest of the scene points the reference lists: the top cell of every 5th heightmap column
    along x and y (an empty column's index −1 wraps to the container's top layer, as in the reference) and the
    point's own projections on the four walls and the floor. Our policy measures to the origin corner, which is
    what the reference computes with sample points in cm and scene points in metres."""
    from robobpp.policies.sdfpack import SDFPack

    def distances(self: Any, obs: Any, xs: Any, ys: Any, zs: Any, offsets: Any) -> Any:
        hm = obs.heightmap
        nx, ny = hm.shape
        nz = int(round(obs.container.height))
        gx, gy = np.arange(0, nx, 5), np.arange(0, ny, 5)
        top = np.ceil(hm[np.ix_(gx, gy)] - 1e-9) - 1
        top = np.where(top < 0, nz - 1, np.minimum(top, nz - 1))  # (I, J): the scene point of each column
        # squared distance from every cell to the nearest scene point, one axis at a time
        b, c = np.arange(ny, dtype=np.float64), np.arange(nz, dtype=np.float64)
        g = np.full((len(gx), ny, nz), np.inf)
        for j, y in enumerate(gy):
            g = np.minimum(g, (b - y)[None, :, None] ** 2 + (c[None, None, :] - top[:, j, None, None]) ** 2)
        a = np.arange(nx, dtype=np.float64)
        d2 = np.full((nx, ny, nz), np.inf)
        for i, x in enumerate(gx):
            d2 = np.minimum(d2, (a - x)[:, None, None] ** 2 + g[i][None])
        edt = np.sqrt(d2)
        ox, oy, oz = offsets
        out = np.empty(len(xs))
        step = max(1, (1 << 21) // max(1, len(ox) * len(oy) * len(oz)))
        for s in range(0, len(xs), step):
            a = (xs[s : s + step, None] + ox[None, :]).astype(np.int64)[:, :, None, None]
            b = (ys[s : s + step, None] + oy[None, :]).astype(np.int64)[:, None, :, None]
            c = (zs[s : s + step, None] + oz[None, :])[:, None, None, :]
            walls = np.minimum(np.minimum(a, nx - 1 - a), np.minimum(b, ny - 1 - b))
            scene = edt[a, b, np.clip(np.rint(c).astype(np.int64), 0, nz - 1)]
            out[s : s + step] = np.minimum(np.minimum(walls, c), scene).sum(axis=(1, 2, 3))
        return out

    SDFPack.distances = distances  # type: ignore[method-assign]


#: Experiment only (``--physics-option``): options of the physical setting (fields of ``PhysicsConfig``).
SETTING_OPTIONS: dict[str, Any] = {}


def make_setting(setting: str) -> Any:
    """The setting for one episode: its name, or a fresh instance with the ``--physics-option`` values."""
    if not SETTING_OPTIONS or setting == "math":
        return setting
    from robobpp.sim import make_setting as build

    return build(setting, **SETTING_OPTIONS)


def make_policy(name: str, spec: Any, item_set: bool = False) -> Any:
    """The policy for one episode; ``item_set`` (experiment only) gives OnlineBPH the smallest side of the
    group's whole item set, as the reference's environment has it, instead of the sides seen so far."""
    from robobpp.core.heightmap import cells_spanned
    from robobpp.policies import load_policy
    from robobpp.policies.onlinebph import OnlineBPH

    policy = load_policy(name)
    if item_set and name == "onlinebph":
        assert isinstance(policy, OnlineBPH)
        smallest = min(min(cells_spanned(b.length), cells_spanned(b.width), b.height) for b in spec.boxes)
        plain_reset = policy.reset

        def reset(info: Any) -> None:
            plain_reset(info)
            policy._smallest = smallest

        policy.reset = reset  # type: ignore[method-assign]
    return policy


def episode_record(r: Any) -> dict[str, Any]:
    """One episode's figures for the JSON: what the table needs, and the evidence for the gaps (how it ended,
    collapses, the execution's dangerous operations and the boxes its motion disturbed)."""
    record: dict[str, Any] = {
        "group": r.group,
        "space_utilization": r.metrics["space_utilization"],
        "boxes_placed": r.boxes_placed,
        "termination": r.termination,
        "termination_detail": r.termination_detail,
        "counters": dict(r.counters),
    }
    if r.setting in PHYSICAL:
        # How far the step (the robot's motion, the release and the settle) moved the boxes placed before it:
        # the largest horizontal shift of their centres between the poses recorded after the previous step
        # and after this one (cm).
        shifts, before = [], None
        for s in r.steps:
            poses = s.extra.get("poses") if s.extra else None
            if poses is None:
                continue
            if before:
                old = np.asarray(before, dtype=np.float64)[:, :2]
                new = np.asarray(poses[: len(before)], dtype=np.float64)[:, :2]
                shifts.append(float(np.max(np.hypot(*(new - old).T))))
            before = poses
        record["steps_shifting_1cm"] = sum(1 for v in shifts if v > 1.0)
        record["max_shift_cm"] = max(shifts, default=0.0)
    if r.setting == "execution":
        steps = [s for s in r.steps if s.action]
        # the operations that were dangerous or collapsed: [step, reasons, boxes woken, collapsed]
        record["marked_steps"] = [
            [
                s.step,
                list(s.extra.get("dangerous_reasons", ())),
                int(s.extra.get("disturbed_boxes", 0)),
                s.collapsed,
            ]
            for s in steps
            if s.dangerous or s.collapsed
        ]
        reasons: Counter[str] = Counter()
        for s in steps:
            reasons.update(s.extra.get("dangerous_reasons", ()))
        record["dangerous_reasons"] = dict(reasons)
        record["disturbed_boxes"] = sum(int(s.extra.get("disturbed_boxes", 0)) for s in steps)
        record["steps_disturbing"] = sum(1 for s in steps if s.extra.get("disturbed_boxes", 0))
        record["failed_grasps"] = sum(1 for s in steps if s.extra.get("failed_grasp"))
        record["plan_status"] = dict(Counter(str(s.extra.get("plan_status")) for s in steps if s.extra))
        record["trajectory_length"] = r.metrics.get("trajectory_length")
    return record


def summarise(episodes: list[dict[str, Any]], cpu_s: float) -> dict[str, Any]:
    """The mean figures of a (dataset, policy) cell from its episodes (kept beside them, so that runs over
    different group ranges can be merged)."""
    return {
        "space_utilization": statistics.mean(e["space_utilization"] for e in episodes),
        "boxes_placed": statistics.mean(e["boxes_placed"] for e in episodes),
        "terminations": dict(Counter(e["termination"] for e in episodes)),
        "groups": sorted(e["group"] for e in episodes),
        "cpu_s": cpu_s,
        "episodes": episodes,
    }


def run(
    dataset: str,
    policy: str,
    setting: str,
    groups: int,
    split: str = "train",
    replay: bool = False,
    item_set: bool = False,
    first_group: int = 0,
) -> dict[str, Any]:
    """One (dataset, heuristic) cell through the package's runner, with this script's experiment hooks."""
    from robobpp.datasets import episode_specs
    from robobpp.reproduction import run_baselines

    cpu0 = time.process_time()
    # A group's boxes depend on its index only, so groups first_group.. are the same as in a longer run.
    specs = episode_specs(dataset, split, first_group + groups)[first_group:]
    episodes = run_baselines(
        specs,
        policy,
        [setting],
        loop=PAPER if replay else CLOSED,
        load=lambda name, spec: make_policy(name, spec, item_set),
        setting_for=make_setting,
    )
    results = [r for rs in episodes for r in rs]
    return summarise([episode_record(r) for r in results], time.process_time() - cpu0)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--setting", choices=SETTINGS, default="math")
    parser.add_argument("--groups", type=int, default=30)
    parser.add_argument(
        "--first-group",
        type=int,
        default=0,
        help="run groups first-group .. first-group+groups-1 (split a long run; --merge pools the ranges)",
    )
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
        help="the paper protocol: plan in Math Pack, replay the actions in --setting (packsim's open loop)",
    )
    parser.add_argument(
        "--sdfpack-step", type=int, help="experiment: SDFPack's search grid step (cm; the reference's is 2)"
    )
    parser.add_argument(
        "--sdfpack-corner",
        help="experiment: the point x,y,z (cm) SDFPack measures its distances from (the reference's: near 0,0,0)",
    )
    parser.add_argument(
        "--sdfpack-scene",
        action="store_true",
        help="experiment: SDFPack's distances to the packed scene in one unit (what the reference's term means)",
    )
    parser.add_argument(
        "--onlinebph-item-set",
        action="store_true",
        help="experiment: OnlineBPH's smallest item side from the group's whole item set (the reference's)",
    )
    parser.add_argument(
        "--physics-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="experiment: a PhysicsConfig field for the physical setting, e.g. mode=full friction_anchor=false",
    )
    parser.add_argument(
        "--verbose", action="store_true", help="also print how each heuristic's episodes ended"
    )
    args = parser.parse_args()
    for option in args.physics_option:
        key, _, value = option.partition("=")
        try:
            SETTING_OPTIONS[key] = json.loads(value)
        except json.JSONDecodeError:
            SETTING_OPTIONS[key] = value
    if args.sdfpack_scene:
        sdfpack_scene_distances()
    if args.sdfpack_step or args.sdfpack_corner:
        import robobpp.policies.sdfpack as sdfpack

        if args.sdfpack_step:
            sdfpack.STEP = args.sdfpack_step
        if args.sdfpack_corner:
            sdfpack.CORNER = tuple(float(v) for v in args.sdfpack_corner.split(","))  # type: ignore[assignment]
    if args.no_support:
        switch_off_support()
    if args.support:
        switch_on_support_in_math()
    datasets = [d for d in args.datasets.split(",") if d]
    policies = [p for p in args.policies.split(",") if p]
    ours: dict[str, dict[str, dict[str, Any]]] = {}
    # What a table may not mix: a Physics run beside the paper's Math column because --setting was left at
    # its default, or closed- and open-loop runs. Group ranges may differ: the episodes are pooled.
    kind = {"setting": args.setting, "open_loop": args.open_loop}
    for path in args.merge or ():
        with open(path) as fh:
            earlier = json.load(fh)
        theirs = {"setting": earlier["setting"], "open_loop": earlier.get("open_loop", False)}
        if path == args.merge[0]:
            kind = theirs
            args.setting, args.open_loop = theirs["setting"], theirs["open_loop"]
        elif theirs != kind:
            parser.error(f"{path} holds {theirs}, not {kind} like {args.merge[0]}")
        for dataset, figures in earlier["ours"].items():
            for policy, fig in figures.items():
                mine = ours.setdefault(dataset, {}).get(policy)
                if mine is None:
                    ours[dataset][policy] = fig
                    continue
                if "episodes" not in fig or "episodes" not in mine:
                    parser.error(f"{path}: {dataset}/{policy} again, without per-episode figures to pool")
                if set(mine["groups"]) & set(fig["groups"]):
                    parser.error(
                        f"{path}: {dataset}/{policy} groups {fig['groups']} overlap {mine['groups']}"
                    )
                ours[dataset][policy] = summarise(
                    mine["episodes"] + fig["episodes"], mine["cpu_s"] + fig["cpu_s"]
                )
    for dataset in datasets:
        ours.setdefault(dataset, {})
        for policy in policies:
            if policy in ours[dataset]:
                continue
            ours[dataset][policy] = run(
                dataset,
                policy,
                args.setting,
                args.groups,
                args.split,
                args.open_loop,
                args.onlinebph_item_set,
                args.first_group,
            )
            fig = ours[dataset][policy]
            print(
                f"# {args.setting} {dataset} {policy}: {fig['space_utilization']:.3f} "
                f"({fig['boxes_placed']:.1f} boxes, {fig['terminations']}, {fig['cpu_s']:.0f} s)",
                flush=True,
            )
            if args.json:  # as it goes: a run stopped early keeps its finished cells
                write_json(args.json, args, ours, {})

    rule = " with the support rule (experiment)" if args.support else ""
    rule = " without the support rule in the candidates (experiment)" if args.no_support else rule
    rule += ", the paper protocol: planned in Math Pack, replayed open loop" if args.open_loop else ""
    rule += f", SDFPack grid step {args.sdfpack_step} cm (experiment)" if args.sdfpack_step else ""
    rule += f", SDFPack distances from {args.sdfpack_corner} (experiment)" if args.sdfpack_corner else ""
    rule += ", SDFPack distances to the scene (experiment)" if args.sdfpack_scene else ""
    rule += ", OnlineBPH bound from the group's item set (experiment)" if args.onlinebph_item_set else ""
    rule += f", physics {', '.join(args.physics_option)} (experiment)" if args.physics_option else ""
    counts = {
        d: sorted({len(ours[d][q].get("groups", ())) or args.groups for q in policies}) for d in datasets
    }
    groups = " / ".join(f"{d} {'–'.join(map(str, counts[d]))}" for d in datasets)
    print(
        f"\n{args.setting.capitalize()} Pack{rule}, Space Utilization, {args.split} split, groups: {groups} (seed 0); "
        f"paper: its test-split tables. {machine()}\n"
    )
    figures = {
        (args.setting, d, q, "space_utilization"): ours[d][q]["space_utilization"]
        for d in datasets
        for q in policies
    }
    comparison = compare(figures, metrics=["space_utilization"])
    print(markdown(comparison))
    summary = {
        d: {"spearman": a.spearman, "mean_abs_diff": a.mean_abs_diff}
        for d in datasets
        if (a := comparison.agreement_of(args.setting, d, "space_utilization")) is not None
    }
    if args.json:
        write_json(args.json, args, ours, summary)
    if args.setting == "execution" or args.verbose:
        print_evidence(ours, datasets, policies, args.setting)


def write_json(path: str, args: argparse.Namespace, ours: dict[str, Any], summary: dict[str, Any]) -> None:
    with open(path, "w") as fh:
        json.dump(
            {
                "setting": args.setting,
                "groups": args.groups,
                "first_group": args.first_group,
                "open_loop": args.open_loop,
                "ours": ours,
                "paper": paper_figures(args.setting),
                "summary": summary,
            },
            fh,
            indent=1,
        )


def paper_figures(setting: str) -> dict[str, dict[str, float]]:
    """The paper's Space Utilization per dataset and method in ``setting`` (package data)."""
    out: dict[str, dict[str, float]] = {}
    for v in paper_tables().values:
        if v.setting == setting and v.metric == "space_utilization":
            out.setdefault(v.dataset, {})[v.method] = v.value
    return out


def count(episodes: list[dict[str, Any]], key: str) -> str:
    """The sum of an episode figure, and over how many episodes when older runs lack it."""
    have = [e[key] for e in episodes if key in e]
    if not have:
        return "–"
    return f"{sum(have)}" + (f" ({len(have)} episodes)" if len(have) < len(episodes) else "")


def print_evidence(ours: dict[str, Any], datasets: list[str], policies: list[str], setting: str) -> None:
    """Per heuristic: how its episodes ended, and (Execution Pack) what the robot did — the evidence for the
    gaps to the paper."""
    robot = setting == "execution"
    head = "| dataset | heuristic | episodes | boxes placed | endings | collapsed placements | steps moving a box > 1 cm |"
    if robot:
        head += (
            " dangerous ops / ops | dangerous reasons | boxes woken by the motion (steps) "
            "| collapses on a dangerous op |"
        )
    print("\n" + head)
    print("|---|---|---:|---:|---|---:|---:|" + ("---:|---|---:|---:|" if robot else ""))
    for d in datasets:
        for q in policies:
            fig = ours[d][q]
            eps = fig.get("episodes", [])
            c: Counter[str] = Counter()
            reasons: Counter[str] = Counter()
            for e in eps:
                c.update(e["counters"])
                reasons.update(e.get("dangerous_reasons", {}))
            endings = ", ".join(f"{k} {v}" for k, v in sorted(fig["terminations"].items()))
            row = (
                f"| {d} | {q} | {len(eps)} | {fig['boxes_placed']:.1f} | {endings} "
                f"| {c['placements_collapsed']} / {c['placements_attempted']} "
                f"| {count(eps, 'steps_shifting_1cm')} |"
            )
            if robot:
                disturbed = (
                    f"{sum(e.get('disturbed_boxes', 0) for e in eps)} "
                    f"({sum(e.get('steps_disturbing', 0) for e in eps)})"
                )
                why = ", ".join(f"{k} {v}" for k, v in reasons.most_common()) or "–"
                marked = [e for e in eps if "marked_steps" in e]
                collapses = [m for e in marked for m in e["marked_steps"] if m[3]]
                on_danger = f"{sum(1 for m in collapses if m[1])} / {len(collapses)}"
                if len(marked) < len(eps):
                    on_danger += f" ({len(marked)} episodes)"
                row += (
                    f" {c['operations_dangerous']} / {c['operations']} | {why} | {disturbed} | {on_danger} |"
                )
            print(row)


if __name__ == "__main__":
    main()
