"""Fast mode against the full dynamic simulation on REAL train groups (CI runs the synthetic fidelity test;
this is the same comparison on the benchmark's own data, too slow for CI).

    python bench/fidelity_physics.py [--groups 5] [--policies dbl,hm] [--noise]

Reports, per dataset: same termination, same boxes placed, and the local-stability difference on episodes that
neither run ended by a collapse (after a collapse, where falling boxes land is chaotic in both modes).
``--noise`` also runs the full simulation with the release gap 0.1 mm larger and reports the same figures for
full against that: the noise floor of the reference itself, which fast mode cannot be expected to beat.
"""

from __future__ import annotations

import argparse
import time

from _common import machine

from robobpp.datasets import DATASETS, episode_specs
from robobpp.episode import EpisodeResult, run_episode
from robobpp.policies import load_policy
from robobpp.sim.physics import PhysicsConfig, PhysicsPack

RUNS = {
    "fast": {"mode": "fast"},
    "full": {"mode": "full"},
    "full+0.1mm": {"mode": "full", "release_gap_cm": PhysicsConfig().release_gap_cm + 0.01},
}


class Tally:
    """Agreement of one run against the reference (full) over a data set's episodes."""

    def __init__(self) -> None:
        self.n = self.same_term = self.same_boxes = self.compared = 0
        self.worst = 0.0

    def add(self, a: EpisodeResult, b: EpisodeResult) -> None:
        self.n += 1
        self.same_term += a.termination == b.termination
        self.same_boxes += a.boxes_placed == b.boxes_placed
        if "collapse" not in (a.termination, b.termination):
            self.compared += 1
            diff = abs((a.metrics["local_stability"] or 0) - (b.metrics["local_stability"] or 0))
            self.worst = max(self.worst, diff * 1000)

    def row(self, name: str, against: str, cpu: float) -> str:
        return (f"| {name} | {against} | {self.n} | {self.same_term}/{self.n} | {self.same_boxes}/{self.n} "
                f"| {self.compared} | {self.worst:.2f} | {cpu:.0f} |")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--groups", type=int, default=5)
    parser.add_argument("--policies", default="dbl,hm")
    parser.add_argument("--noise", action="store_true", help="also full vs full with a 0.1 mm larger gap")
    args = parser.parse_args()
    runs = ["fast", "full"] + (["full+0.1mm"] if args.noise else [])
    print(f"machine: {machine()}")
    rows = []
    totals = {run: Tally() for run in runs[::2]}
    for name in DATASETS:
        tallies = {run: Tally() for run in runs[::2]}  # fast vs full, full+0.1mm vs full
        cpu = dict.fromkeys(runs, 0.0)
        for policy in args.policies.split(","):
            for spec in episode_specs(name, groups=args.groups):
                results = {}
                for run in runs:
                    t0 = time.process_time()
                    results[run] = run_episode(spec, load_policy(policy), PhysicsPack(**RUNS[run]))
                    cpu[run] += time.process_time() - t0
                line = " / ".join(f"{results[r].termination}{results[r].boxes_placed}" for r in runs)
                print(f"# {name} {policy} group {spec.group}: {' / '.join(runs)} = {line}", flush=True)
                for run, tally in tallies.items():
                    tally.add(results[run], results["full"])
                    totals[run].add(results[run], results["full"])
        rows += [
            tallies[run].row(name, f"{run} vs full", cpu[run]) + f" {cpu['full']:.0f} |" for run in tallies
        ]
    print("| dataset | compared | episodes | same termination | same boxes placed | compared (no collapse) "
          "| max LS diff (mm) | its CPU s | full CPU s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    for run, tally in totals.items():
        print(f"all: {run} vs full: same termination {tally.same_term}/{tally.n}, "
              f"max LS diff {tally.worst:.2f} mm over {tally.compared} without collapse")  # fmt: skip


if __name__ == "__main__":
    main()
