"""Where a board publication's time goes: the board worker's stages, timed, for finished submissions of
middling quality on a seeded database (``bench_boards.py --seed-only``; use a fresh copy: it adds
submissions).

Runs the board worker's publisher in this process: its first (full) publication, then ``--updates`` more, one
per new finished submission, each with the CPU seconds of its stages (setting the boards' rows from the runs
read, the engine's boards and grids, building the stored parts, hashing the rows, the SQL write and its wall
time) and the bytes of the parts it built.

    python bench/publish_stages.py --database-url URL [--updates 4]
"""

from __future__ import annotations

import argparse
import collections
import functools
import tempfile
import time
from pathlib import Path
from typing import Any

from bench_server import bench_settings, seed_rows
from sqlalchemy import text

from robobpp.boards import grid as scoring_grid
from robobpp.boards import matrix as scoring_engine
from robobpp.boards import store as board_store
from robobpp.boards import worker as board_worker
from robobpp.server.bootstrap import bootstrap
from robobpp.server.runtime import Runtime
from robobpp.vocabulary import DATASETS, SETTINGS

STAGES: collections.defaultdict[str, float] = collections.defaultdict(float)


def timed(owner: Any, name: str, label: str) -> None:
    """Wrap ``owner.name`` to add its CPU seconds (and, for the write, its wall seconds) to STAGES."""
    inner = getattr(owner, name)

    @functools.wraps(inner)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        cpu, wall = time.process_time(), time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            STAGES[f"{label}_cpu_s"] += time.process_time() - cpu
            if label == "write":
                STAGES["write_wall_s"] += time.perf_counter() - wall

    setattr(owner, name, wrapper)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--database-url", required=True)
    parser.add_argument("--updates", type=int, default=4)
    args = parser.parse_args()

    timed(scoring_engine.BoardMatrix, "apply", "rows")
    timed(scoring_engine.BoardMatrix, "board", "boards")
    timed(scoring_grid.GridMatrix, "grid", "grids")
    timed(board_worker.BoardPublisher, "_rows_hashed", "hash")
    timed(board_worker.BoardPublisher, "_write", "write")
    parts_of = board_store.parts_of

    def counted_parts(value: Any) -> Any:
        cpu = time.process_time()
        stored = parts_of(value)
        STAGES["parts_cpu_s"] += time.process_time() - cpu
        STAGES["chunks_mb"] += sum(len(b) for b in stored.chunks.values()) / 1e6
        return stored

    board_worker.parts_of = counted_parts  # type: ignore[attr-defined,assignment]  # the name the worker calls (it imports it)

    runtime = Runtime(
        bench_settings(args.database_url, Path(tempfile.mkdtemp(prefix="robobpp-bench-publish-")))
    )
    bootstrap(runtime)
    publisher = board_worker.BoardPublisher(runtime.read_session, runtime.session, DATASETS, SETTINGS)
    started = time.perf_counter()
    publisher.publish("private")
    stages = ", ".join(f"{k} {v:.2f}" for k, v in STAGES.items())
    print(f"first publication: {time.perf_counter() - started:.1f} s; {stages}")
    with runtime.read_session() as s:
        count = s.execute(text("SELECT count(*) FROM submissions")).scalar_one()
    for _ in range(args.updates):
        while count % 50 in (7, 23):  # bench_server makes these failed or partial
            seed_rows(runtime, 1, first=count)
            count += 1
            publisher.publish("private")
        seed_rows(runtime, 1, first=count, fixed_quality=0.5)
        count += 1
        STAGES.clear()
        wall, cpu = time.perf_counter(), time.process_time()
        publisher.publish("private")
        stages = ", ".join(f"{k} {v:.2f}" for k, v in STAGES.items())
        print(
            f"publication: {time.perf_counter() - wall:.2f} s wall, {time.process_time() - cpu:.2f} s CPU, "
            f"{publisher.rows_written} rows written; {stages}"
        )
    runtime.dispose()


if __name__ == "__main__":
    main()
