"""The lookup attack on the private groups, before (sampler v1) and after (the current sampler), and the group
statistics the new Repetitive rule keeps.

For each dataset, the attack (:mod:`robobpp.datasets.lookup`) shows a group's boxes one by one and searches them
as a run of consecutive boxes in every public pool (train and test of every dataset); a group is *told* when every
match continues exactly as the group does. It runs on the draws a server makes: ``build_private`` into a fresh
directory and the hold-out draw beside it (each with its own secret seed, as ``robobpp serve`` builds them), and on
a fresh ``build-private`` draw; "before" draws the same seeds with version 1's rules (every split with the
registry's ``sampling``), "after" with the current sampler.

    python bench/lookup_attack.py                      # fresh secret seeds, 30 groups per draw
    python bench/lookup_attack.py --seed 1 --json out.json
    python bench/lookup_attack.py --stats 2000         # also: Repetitive test groups, v1 against current rule
    python bench/lookup_attack.py --stats 2000 --candidates   # and the rules tried before palette (experiment)
"""

from __future__ import annotations

import argparse
import json
import secrets
import statistics
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from robobpp.core import EpisodeSpec
from robobpp.datasets import DATASETS, EVAL_GROUPS, build_private, group_seed, load_pool, load_private
from robobpp.datasets.lookup import PublicIndex, public_index
from robobpp.datasets.private import HOLDOUT_DIR, PRIVATE_SPLIT
from robobpp.datasets.registry import GROUP_SIZE
from robobpp.datasets.sampling import SAMPLER_VERSION, sample_indices


def v1_groups(dataset: str, seed: int, groups: int, split: str = PRIVATE_SPLIT) -> list[np.ndarray]:
    """The boxes sampler version 1 drew for these groups: the registry's ``sampling`` on every split."""
    pool = load_pool(dataset, split)
    rule = DATASETS[dataset].sampling
    out = []
    for g in range(groups):
        rng = np.random.default_rng(group_seed(dataset, split, seed, g))
        idx = sample_indices(pool, rule, rng, GROUP_SIZE)
        out.append(np.column_stack([pool.dims[idx], pool.masses[idx]]))
    return out


def as_table(spec: EpisodeSpec) -> np.ndarray:
    return np.array([[b.length, b.width, b.height, b.mass] for b in spec.boxes])


def attack(index: PublicIndex, groups: list[np.ndarray]) -> dict[str, Any]:
    looks = [index.lookup(g) for g in groups]
    told = [x.told_after for x in looks if x.told_after is not None]
    prefix = [x.matched_prefix for x in looks]
    return {
        "groups": len(looks),
        "told": len(told),
        "told_within_10": sum(k <= 10 for k in told),
        "median_boxes_shown": statistics.median(told) if told else None,
        "max_boxes_shown": max(told) if told else None,
        "matched_prefix_median": statistics.median(prefix),
        "matched_prefix_max": max(prefix),
    }


def draws(seed: int | None) -> dict[str, int]:
    """Seeds of the three draws: a server's private split and its hold-out draw, and a fresh build-private."""
    names = ("server private", "server hold-out", "fresh build-private")
    return {name: secrets.randbits(63) if seed is None else seed + i for i, name in enumerate(names)}


def run_attack(seed: int | None, groups: int) -> list[dict[str, Any]]:
    index = public_index()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, (draw, draw_seed) in enumerate(draws(seed).items()):
            # Where the server keeps them (robobpp/server/bootstrap.py): the hold-out beside the private set.
            root = Path(tmp) / ("private" if i != 1 else f"private/{HOLDOUT_DIR}")
            if i == 2:
                root = Path(tmp) / "fresh"
            build_private(root, seed=draw_seed, groups=groups)
            for dataset in DATASETS:
                after = [as_table(s) for s in load_private(dataset, root)]
                before = v1_groups(dataset, draw_seed, groups)
                rows.append(
                    {
                        "draw": draw,
                        "dataset": dataset,
                        "before": attack(index, before),
                        "after": attack(index, after),
                    }
                )
    return rows


# ---- group statistics -------------------------------------------------------------------------------------


def group_stats(groups: list[np.ndarray], pool_table: np.ndarray) -> dict[str, Any]:
    sizes = [len({tuple(r) for r in g[:, :3].tolist()}) for g in groups]
    run_lengths: list[int] = []
    for g in groups:
        change = np.flatnonzero(np.any(g[1:] != g[:-1], axis=1))
        run_lengths += np.diff(np.r_[0, change + 1, len(g)]).tolist()
    volume_l = np.concatenate([g[:, :3].prod(axis=1) / 1000 for g in groups])
    # Share of boxes per size, against the pool's (total variation distance: 0 = the same shares).
    _, pool_inverse = np.unique(pool_table[:, :3], axis=0, return_inverse=True)
    keys = {tuple(r): i for i, r in enumerate(np.unique(pool_table[:, :3], axis=0).tolist())}
    drawn = np.bincount([keys[tuple(r)] for g in groups for r in g[:, :3].tolist()], minlength=len(keys))
    share = np.bincount(pool_inverse.ravel(), minlength=len(keys)) / len(pool_table)
    rl = np.array(run_lengths)
    change = np.flatnonzero(np.any(pool_table[1:] != pool_table[:-1], axis=1))
    starts = np.r_[0, change + 1]
    lengths = np.diff(np.r_[starts, len(pool_table)])
    long_run_sizes = sorted(
        {int(pool_inverse.ravel()[a]) for a, n in zip(starts, lengths, strict=True) if n > GROUP_SIZE}
    )
    return {
        "groups": len(groups),
        "distinct_sizes_p10_p50_p90": np.percentile(sizes, [10, 50, 90]).tolist(),
        "repeat_rate": round(float(np.mean([(GROUP_SIZE - s) / GROUP_SIZE for s in sizes])), 3),
        "runs_per_group": round(len(rl) / len(groups), 1),
        "run_length_mean": round(float(rl.mean()), 2),
        "run_length_p50_p90_p99_max": [*np.percentile(rl, [50, 90, 99]).tolist(), int(rl.max())],
        "boxes_in_runs_of_5_or_more": round(float(rl[rl >= 5].sum() / rl.sum()), 3),
        "volume_l_p10_p50_p90": [round(v, 2) for v in np.percentile(volume_l, [10, 50, 90]).tolist()],
        "volume_l_mean": round(float(volume_l.mean()), 2),
        "mass_kg_mean": round(float(np.concatenate([g[:, 3] for g in groups]).mean()), 3),
        "size_share_tv_to_pool": round(float(0.5 * np.abs(drawn / drawn.sum() - share).sum()), 3),
        # the sizes of the pool's runs longer than a group: drawn share / pool share
        "long_run_sizes_share_ratio": [
            round(float(drawn[i] / drawn.sum() / share[i]), 2) for i in long_run_sizes
        ],
    }


def candidates(groups: int, seed: int) -> dict[str, list[np.ndarray]]:
    """Experiment: the rules tried for the test split before ``palette`` (docs/datasets.md says why each lost).

    records: records drawn uniformly with replacement from the whole pool, each expanded to its quantity;
    local records / local runs: records (runs) drawn with replacement from those a random window covers;
    palette, unweighted: the palette rule with every run equally likely (no L / shown(L) weight)."""
    from robobpp.datasets.sampling import runs

    pool = load_pool("repetitive", PRIVATE_SPLIT)
    table = np.column_stack([pool.dims, pool.masses])
    run_start, run_length = runs(pool)
    record_start = np.searchsorted(pool.record_index, np.arange(pool.records))
    quantity = np.bincount(pool.record_index, minlength=pool.records)
    rng = np.random.default_rng(seed)

    def expand(units: np.ndarray, start: np.ndarray, length: np.ndarray) -> np.ndarray:
        picked: list[int] = []
        while len(picked) < GROUP_SIZE:
            u = int(units[rng.integers(len(units))])
            picked += range(int(start[u]), int(start[u] + length[u]))
        return table[picked[:GROUP_SIZE]]

    out: dict[str, list[np.ndarray]] = {
        "records": [],
        "local records": [],
        "local runs": [],
        "palette, unweighted": [],
    }
    for _ in range(groups):
        first = int(rng.integers(0, len(pool) - GROUP_SIZE + 1))
        window = np.arange(first, first + GROUP_SIZE)
        covered = np.unique(np.searchsorted(run_start, window, side="right") - 1)
        out["records"].append(expand(np.arange(pool.records), record_start, quantity))
        out["local records"].append(expand(np.unique(pool.record_index[window]), record_start, quantity))
        out["local runs"].append(expand(covered, run_start, run_length))
        palette = rng.integers(0, len(run_start), size=len(covered))
        out["palette, unweighted"].append(expand(palette, run_start, run_length))
    return out


def window_leak(groups: list[np.ndarray], pool_table: np.ndarray, shown: int = 10) -> dict[str, Any]:
    """A softer attack, on rules that draw from a stretch of the pool: after ``shown`` boxes, take every window of
    the test pool holding all the sizes seen, and guess that the sizes still unseen come from those windows.
    Reports how many of the group's later boxes of an unseen size the guess holds, and how many sizes it names."""
    _, inverse = np.unique(pool_table[:, :3], axis=0, return_inverse=True)
    sizes = {tuple(r): i for i, r in enumerate(np.unique(pool_table[:, :3], axis=0).tolist())}
    inverse = inverse.ravel()
    starts = np.arange(len(inverse) - GROUP_SIZE + 1)
    holds = np.zeros((len(starts), len(sizes)), dtype=bool)
    for offset in range(GROUP_SIZE):
        holds[starts, inverse[starts + offset]] = True
    caught = unseen = 0
    named: list[int] = []
    for g in groups:
        ids = np.array([sizes[tuple(r)] for r in g[:, :3].tolist()])
        seen = np.zeros(len(sizes), dtype=bool)
        seen[ids[:shown]] = True
        windows = holds[np.all(holds[:, seen], axis=1)]
        guess = windows.any(axis=0) & ~seen
        later = ids[shown:][~seen[ids[shown:]]]
        caught += int(guess[later].sum())
        unseen += len(later)
        named.append(int(guess.sum()))
    return {
        "later_boxes_of_unseen_sizes_guessed": round(caught / max(unseen, 1), 3),
        "sizes_named_median": float(np.median(named)),
        "of_sizes": len(sizes),
    }


def run_stats(groups: int, seed: int, tried: bool = False) -> dict[str, Any]:
    from robobpp.datasets import episode_specs

    pool = load_pool("repetitive", PRIVATE_SPLIT)
    table = np.column_stack([pool.dims, pool.masses])
    after = [as_table(s) for s in episode_specs("repetitive", PRIVATE_SPLIT, groups=groups, seed=seed)]
    rule = DATASETS["repetitive"].sampling_of(PRIVATE_SPLIT)
    drawn = {"v1 (consecutive)": v1_groups("repetitive", seed, groups), f"v{SAMPLER_VERSION} ({rule})": after}
    if tried:
        drawn |= {f"tried: {name}": g for name, g in candidates(groups, seed).items()}
    index = public_index()
    return {
        name: group_stats(g, table) | window_leak(g, table) | looked_up(index, g) for name, g in drawn.items()
    }


def looked_up(index: PublicIndex, groups: list[np.ndarray]) -> dict[str, Any]:
    looks = [index.lookup(g) for g in groups]
    prefix = [x.matched_prefix for x in looks]
    return {
        "told": sum(x.told_after is not None for x in looks),
        "whole_group_a_public_run": sum(p == GROUP_SIZE for p in prefix),
        "one_box_only": sum(len(np.unique(g, axis=0)) == 1 for g in groups),
        "public_prefix_p50_p90_p99": np.percentile(prefix, [50, 90, 99]).tolist(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, help="first of the draws' seeds (default: fresh secret seeds)")
    parser.add_argument("--groups", type=int, default=EVAL_GROUPS)
    parser.add_argument("--stats", type=int, default=0, help="also compare this many Repetitive test groups")
    parser.add_argument("--candidates", action="store_true", help="with --stats: the rules tried before")
    parser.add_argument("--json", help="also write every figure here")
    args = parser.parse_args()
    out: dict[str, Any] = {"sampler": SAMPLER_VERSION, "attack": run_attack(args.seed, args.groups)}
    print(
        f"Lookup attack, {args.groups} groups per draw; told: every public match continues as the group does"
    )
    print("| draw | dataset | before (v1): told / groups (≤ 10 boxes), median boxes | after: told / groups |")
    print("|---|---|---|---|")
    for row in out["attack"]:
        b, a = row["before"], row["after"]
        print(
            f"| {row['draw']} | {row['dataset']} | {b['told']} / {b['groups']} ({b['told_within_10']}), "
            f"{b['median_boxes_shown']} | {a['told']} / {a['groups']} (longest public prefix: median "
            f"{a['matched_prefix_median']}, max {a['matched_prefix_max']}) |"
        )
    if args.stats:
        out["stats"] = run_stats(args.stats, args.seed or 0, args.candidates)
        print(f"\nRepetitive test groups ({args.stats}), v1 against v{SAMPLER_VERSION}:")
        for name, figures in out["stats"].items():
            print(name, json.dumps(figures))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
