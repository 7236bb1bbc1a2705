"""Wall time of `robobpp evaluate` with --jobs 1 and --jobs N on the same Physics Pack episodes (whole command,
process start and data loading included), and a check that the figures are identical.

    python bench/bench_evaluate_jobs.py [--groups 6] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import machine


def run(jobs: int, groups: int, out: Path) -> float:
    started = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "robobpp.cli",
            "evaluate",
            "--policy",
            "dbl",
            "--dataset",
            "all",
            "--setting",
            "physics",
            "--groups",
            str(groups),
            "--jobs",
            str(jobs),
            "--json",
            str(out),
        ],
        check=True,
        capture_output=True,
    )
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--groups", type=int, default=6)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        one, many = Path(tmp) / "1.json", Path(tmp) / "n.json"
        t1 = run(1, args.groups, one)
        tn = run(args.jobs, args.groups, many)

        def figures(path: Path) -> list[tuple[str, int, float]]:
            return [
                (e["episode_id"], e["boxes_placed"], e["metrics"]["space_utilization"])
                for e in json.loads(path.read_text())["episodes"]
            ]

        same = figures(one) == figures(many)
    print(f"machine: {machine()}")
    print(f"| episodes | --jobs 1 (s) | --jobs {args.jobs} (s) | speed-up | identical figures |")
    print("|---|---|---|---|---|")
    print(f"| {3 * args.groups} | {t1:.1f} | {tn:.1f} | {t1 / tn:.2f}× | {same} |")


if __name__ == "__main__":
    main()
