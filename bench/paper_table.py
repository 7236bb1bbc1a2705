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
    python bench/paper_table.py --policies sdfpack --sdfpack-step 1   # experiment: SDFPack on the 1 cm grid
    python bench/paper_table.py --policies sdfpack --sdfpack-corner 4.4,0.7,2.4   # experiment: distances from there
    nice python bench/paper_table.py --policies sdfpack --groups 10 --sdfpack-scene   # experiment: true distances
    python bench/paper_table.py --policies onlinebph --onlinebph-item-set   # experiment: the group's item set
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


def make_policy(name: str, spec: Any, item_set: bool = False) -> Any:
    """The policy for one episode; ``item_set`` (experiment only) gives OnlineBPH the smallest side of the
    group's whole item set, as the reference's environment has it, instead of the sides seen so far."""
    from robobpp.core.heightmap import cells_spanned
    from robobpp.policies import load_policy

    policy = load_policy(name)
    if item_set and name == "onlinebph":
        smallest = min(min(cells_spanned(b.length), cells_spanned(b.width), b.height) for b in spec.boxes)
        plain_reset = policy.reset

        def reset(info: Any) -> None:
            plain_reset(info)
            policy._smallest = smallest

        policy.reset = reset
    return policy


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
    dataset: str,
    policy: str,
    setting: str,
    groups: int,
    split: str = "train",
    replay: bool = False,
    item_set: bool = False,
) -> dict[str, Any]:
    from robobpp.datasets import episode_specs
    from robobpp.episode import run_episode

    cpu0 = time.process_time()
    specs = episode_specs(dataset, split, groups)
    if replay:
        results = [open_loop(s, policy, setting) for s in specs]
    else:
        results = [run_episode(s, make_policy(policy, s, item_set), setting) for s in specs]
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
    args = parser.parse_args()
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
                dataset,
                policy,
                args.setting,
                args.groups,
                args.split,
                args.open_loop,
                args.onlinebph_item_set,
            )
            fig = ours[dataset][policy]
            print(f"# {args.setting} {dataset} {policy}: {fig['space_utilization']:.3f} "
                  f"({fig['boxes_placed']:.1f} boxes, {fig['terminations']}, {fig['cpu_s']:.0f} s)", flush=True)  # fmt: skip

    col = {d: DATASETS.index(d) for d in datasets}
    rule = " with the support rule (experiment)" if args.support else ""
    rule = " without the support rule in the candidates (experiment)" if args.no_support else rule
    rule += ", open loop: planned in Math Pack, replayed (experiment)" if args.open_loop else ""
    rule += f", SDFPack grid step {args.sdfpack_step} cm (experiment)" if args.sdfpack_step else ""
    rule += f", SDFPack distances from {args.sdfpack_corner} (experiment)" if args.sdfpack_corner else ""
    rule += ", SDFPack distances to the scene (experiment)" if args.sdfpack_scene else ""
    rule += ", OnlineBPH bound from the group's item set (experiment)" if args.onlinebph_item_set else ""
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
