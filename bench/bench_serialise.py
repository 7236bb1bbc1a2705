"""Serialising published board rows: ``robobpp.boards.store.to_json`` (orjson) against the json
module with the options it replaced, on rows shaped as the all-entries view stores them.

    python bench/bench_serialise.py [--rows 10000] [--repeats 5]

Prints the best of ``repeats`` for each, checks that both give the same values for every row (parsed back),
and counts the rows whose bytes differ (orjson writes a float under 1e-4 without an exponent).
"""

from __future__ import annotations

import argparse
import json
import random
import time
from datetime import UTC, datetime
from typing import Any

from _common import machine

from robobpp.boards.store import to_json
from robobpp.scoring.metrics import metrics_for


def _default(value: object) -> str:  # what the json module was given before orjson
    if isinstance(value, datetime):
        return value.isoformat().replace("+00:00", "Z")
    raise TypeError(f"cannot serialise {type(value).__name__}")


def json_module(data: Any) -> bytes:
    return json.dumps(data, default=_default, allow_nan=False, separators=(",", ":")).encode()


def row(rng: random.Random, sid: int) -> dict[str, Any]:
    """An Execution Pack entry as stored (its eight metrics, intervals, normalised metrics, extras)."""
    keys = [m.key for m in metrics_for("execution")]
    return {
        "submission_id": sid,
        "name": f"policy-{sid}",
        "participant": f"team-{sid % 100:03d}",
        "baseline": False,
        "metrics": {k: rng.random() for k in keys},
        "extras": {
            "episodes": 30,
            "terminations": {"collapse": 29, "plan_done": 1},
            "pph": rng.uniform(100, 900),
        },
        "completed_at": datetime(
            2026, 11, 26, 12, rng.randrange(60), rng.randrange(60), rng.randrange(10**6), UTC
        ),
        "verification": None,
        "rank": None,
        "rank_low": rng.randrange(1, 50),
        "rank_high": rng.randrange(50, 500),
        "score": rng.random(),
        "score_low": rng.random(),
        "score_high": rng.random(),
        "stable": rng.random(),
        "stable_low": rng.random(),
        "stable_high": rng.random(),
        "normalized": {k: rng.random() for k in keys},
        "intervals": {k: [rng.random(), rng.random()] for k in keys},
        "best": False,
    }


def best_of(fn: Any, rows: list[dict[str, Any]], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for r in rows:
            fn(r)
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rows", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    rng = random.Random(0)
    rows = [row(rng, sid) for sid in range(args.rows)]
    same = all(json.loads(to_json(r)) == json.loads(json_module(r)) for r in rows)
    other_bytes = sum(to_json(r) != json_module(r) for r in rows)
    old, new = best_of(json_module, rows, args.repeats), best_of(to_json, rows, args.repeats)
    print(machine())
    print(f"{args.rows:,} rows: json module {old:.3f} s, to_json (orjson) {new:.3f} s, {old / new:.1f}x")
    print(f"the same values for every row: {same}; other bytes (float notation) in {other_bytes:,} rows")


if __name__ == "__main__":
    main()
