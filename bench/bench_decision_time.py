"""Decision Time of one policy measured the ways a server can, and what serving the built-ins costs.

    python bench/bench_decision_time.py resolution --policy dbl --dataset repetitive --groups 5 --rounds 5
    python bench/bench_decision_time.py overhead --setting math

``resolution``: per round, the run figure (mean over the groups) of the policy in-process (what the server's
workers did before), served by the worker (``worker.builtin.ServedBuiltin``: the SDK's server on loopback in the
worker's process) and served by a participant (``serve`` in a process of its own, signed); the spread of the two
served ways over all rounds, and whether the placements are the same. ``overhead``: the demo's episodes (every
baseline, 3 datasets × 2 test groups) in-process and served by the worker, wall time.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

from _common import machine

from robobpp.client.remote import RemotePolicy
from robobpp.datasets import episode_specs
from robobpp.episode import run_episode
from robobpp.policies import BASELINES, LEARNED, load_policy
from robobpp.vocabulary import DATASETS
from robobpp.worker.builtin import ServedBuiltin

SECRET = "participant-secret-1"


def _run(specs: list[Any], make: Callable[[], Any], setting: str) -> tuple[float, float, float]:
    """(decision time ms, utilisation, wall s): means over the groups."""
    times, utils, wall = [], [], time.perf_counter()
    for spec in specs:
        r = run_episode(spec, make(), setting)
        t, u = r.metrics["decision_time"], r.metrics["space_utilization"]
        assert t is not None and u is not None, r.termination_detail
        times.append(t)
        utils.append(u)
    return 1000 * statistics.fmean(times), statistics.fmean(utils), time.perf_counter() - wall


def resolution(policy: str, dataset: str, groups: int, rounds: int) -> None:
    specs = list(episode_specs(dataset, "test", groups=groups, seed=0))
    code = (
        "from robobpp.client.serve import serve; from robobpp.policies import load_policy; "
        f"serve(load_policy({policy!r}), port=0, secret={SECRET!r})"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    url = proc.stdout.readline().split(" on ")[1].split(" ")[0]
    ways: dict[str, Callable[[], Any]] = {
        "in-process": lambda: load_policy(policy),
        "served by the worker": lambda: ServedBuiltin(policy, step_timeout_s=10, episode_timeout_s=1800),
        "served by a participant": lambda: RemotePolicy(url, SECRET, probe_network=True, name=policy),
    }
    rows: dict[str, list[tuple[float, float, float]]] = {k: [] for k in ways}
    try:
        for _ in range(rounds):
            for way, make in ways.items():
                rows[way].append(_run(specs, make, "math"))
    finally:
        proc.terminate()
    print(f"{policy}, {dataset} test, {groups} groups, {rounds} rounds, Math; {machine()}")
    print("| way | decision time per round (ms) | utilisation | wall per round |\n|---|---|---|---|")
    for way, v in rows.items():
        same = "same every round" if len({round(u, 12) for _, u, _ in v}) == 1 else "DIFFERS"
        times = " ".join(f"{t:.2f}" for t, _, _ in v)
        print(f"| {way} | {times} | {v[0][1]:.4f} ({same}) | {statistics.fmean(w for *_, w in v):.2f} s |")
    utils = {round(u, 12) for v in rows.values() for _, u, _ in v}
    served = [t for way in ("served by the worker", "served by a participant") for t, _, _ in rows[way]]
    print(
        f"placements alike in every way: {len(utils) == 1}; spread of the served ways: {max(served) - min(served):.2f} ms"
    )


def overhead(setting: str) -> None:
    names = [*BASELINES, *LEARNED]
    specs = [s for d in DATASETS for s in episode_specs(d, "test", groups=2, seed=0)]
    ways: dict[str, Callable[[str], Any]] = {
        "in-process": load_policy,
        "served by the worker": lambda n: ServedBuiltin(n, step_timeout_s=10, episode_timeout_s=1800),
    }
    print(f"{setting}: {len(names)} baselines × {len(specs)} episodes; {machine()}")
    for way, make in ways.items():
        started, placed = time.perf_counter(), 0
        for name in names:
            for spec in specs:
                placed += run_episode(spec, make(name), setting).boxes_placed
        wall = time.perf_counter() - started
        print(f"| {way} | {placed} placements | {wall:.1f} s | {1000 * wall / placed:.2f} ms a placement |")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="what", required=True)
    res = sub.add_parser("resolution")
    res.add_argument("--policy", default="dbl")
    res.add_argument("--dataset", default="repetitive")
    res.add_argument("--groups", type=int, default=5)
    res.add_argument("--rounds", type=int, default=5)
    over = sub.add_parser("overhead")
    over.add_argument("--setting", default="math")
    args = parser.parse_args()
    if args.what == "resolution":
        resolution(args.policy, args.dataset, args.groups, args.rounds)
    else:
        overhead(args.setting)


if __name__ == "__main__":
    main()
