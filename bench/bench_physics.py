"""Physics Pack: CPU seconds per box and peak memory per worker process, DBL on 80-box train groups.

Each (dataset, mode) runs in its own fresh process (like one episode worker) and reports its CPU time and
peak RSS. ``--full`` also runs the full dynamic simulation (every box simulated, whole 200-step window) as the
in-run reference, printing the speed-up and whether both ended the same way.

    python bench/bench_physics.py [--groups 1] [--full] [--synthetic]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import statistics
import time
from typing import Any

from _common import machine


def _specs(dataset: str, groups: int, synthetic: bool) -> list[Any]:
    if synthetic:
        from robobpp.datasets.synthetic import synthetic_episode_specs

        return synthetic_episode_specs(groups, seed=0, container=dataset)
    from robobpp.datasets import episode_specs

    return episode_specs(dataset, split="train", groups=groups)


def _worker(dataset: str, mode: str, groups: int, synthetic: bool, out: Any) -> None:
    from robobpp.episode import Episode
    from robobpp.policies import load_policy
    from robobpp.sim.physics import PhysicsPack

    rows = []
    for spec in _specs(dataset, groups, synthetic):
        policy = load_policy("dbl")
        episode = Episode(spec, PhysicsPack(mode=mode))
        policy.reset(episode.info)
        per_box: list[float] = []
        cpu0, wall0 = time.process_time(), time.perf_counter()
        while not episode.done:
            t0 = time.process_time()
            obs = episode.observe()
            action = policy.act(obs)
            episode.step(action, 0.0)
            per_box.append(time.process_time() - t0)
        result = episode.result("dbl")
        episode.setting.close()
        rows.append(
            {
                "group": spec.group,
                "steps": len(per_box),
                "cpu": time.process_time() - cpu0,
                "wall": time.perf_counter() - wall0,
                "median": statistics.median(per_box) if per_box else 0.0,
                "termination": result.termination,
                "placed": result.boxes_placed,
                "ls_mm": (result.metrics.get("local_stability") or 0.0) * 1000,
                "static": result.metrics.get("static_stability"),
                "util": result.metrics["space_utilization"],
            }
        )
    out.put({"rows": rows, "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024})


def run(dataset: str, mode: str, groups: int, synthetic: bool) -> dict[str, Any]:
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_worker, args=(dataset, mode, groups, synthetic, queue))
    proc.start()
    data: dict[str, Any] = queue.get()
    proc.join()
    return data


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--groups", type=int, default=1)
    parser.add_argument("--full", action="store_true", help="also run the full simulation as reference")
    parser.add_argument(
        "--synthetic", action="store_true", help="synthetic groups in each dataset's container"
    )
    args = parser.parse_args()
    from robobpp.datasets import DATASETS

    print(f"machine: {machine()}")
    print(
        "| dataset | mode | boxes | CPU s/box (mean) | CPU s/box (median) | peak RSS (MB) | termination | "
        "placed | Local Stab. (mm) | Static Stab. | Util. |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in DATASETS:
        results = {}
        for mode in ("fast", "full") if args.full else ("fast",):
            data = run(name, mode, args.groups, args.synthetic)
            results[mode] = data
            rows = data["rows"]
            steps = sum(r["steps"] for r in rows)
            cpu = sum(r["cpu"] for r in rows)
            med = statistics.median(r["median"] for r in rows)
            term = ", ".join(sorted({r["termination"] for r in rows}))
            placed = statistics.mean(r["placed"] for r in rows)
            ls = statistics.mean(r["ls_mm"] for r in rows)
            ss = statistics.mean(r["static"] or 0.0 for r in rows)
            util = statistics.mean(r["util"] for r in rows)
            print(
                f"| {name} | {mode} | {steps} | {cpu / max(1, steps):.4f} | {med:.4f} | {data['rss_mb']:.0f} | "
                f"{term} | {placed:.1f} | {ls:.2f} | {ss:.3f} | {util:.3f} |",
                flush=True,
            )
        if args.full:
            fast, full = results["fast"]["rows"], results["full"]["rows"]
            ratio = (sum(r["cpu"] for r in full) / sum(r["steps"] for r in full)) / (
                sum(r["cpu"] for r in fast) / sum(r["steps"] for r in fast)
            )
            same = sum(a["termination"] == b["termination"] for a, b in zip(fast, full, strict=True))
            print(
                f"|  | full/fast CPU per box {ratio:.1f}x; same termination {same}/{len(fast)} |  |  |  |  |  |  |  |  |  |"
            )


if __name__ == "__main__":
    main()
