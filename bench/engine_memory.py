"""What the board engine keeps after its first, full computation of a seeded database's private track
(``bench_boards.py --seed-only``): Python's traced allocations still alive (``tracemalloc``), grouped by the
line that made them, and the process's resident memory before and after; or, with ``--publish``, the
board worker's publisher instead of the engine alone (its first publication, written to the database: use a
fresh copy), resident after it.

    OPENBLAS_NUM_THREADS=1 python bench/engine_memory.py --database-url URL [--top 15] [--no-trace]
    OPENBLAS_NUM_THREADS=1 python bench/engine_memory.py --database-url URL --publish --no-trace
    OPENBLAS_NUM_THREADS=1 python bench/engine_memory.py --database-url URL --own-process --no-trace [--publish]

Tracing slows the computation about fivefold; ``--no-trace`` gives the resident figures and the CPU seconds
alone. Resident memory is read from ``/proc/self/statm`` (Linux).

By default the engine runs in this process, which has imported the server (FastAPI, pydantic, … : ≈ 114 MB
before the engine starts). ``--own-process``: in a spawned process that imports only what the deployed board
worker's process does (``robobpp.boards.worker``, with its own connections: ``worker_for_url``), so "after" is
what that process holds.
"""

from __future__ import annotations

import argparse
import multiprocessing
import resource
import tempfile
import time
import tracemalloc
from pathlib import Path

from robobpp.boards.engine import BoardEngine, SessionFactory
from robobpp.boards.worker import worker_for_url
from robobpp.vocabulary import DATASETS, SETTINGS


def resident_mb() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * resource.getpagesize() / 2**20


def measure(url: str, publish: bool, trace: bool, top: int, reads: SessionFactory | None = None) -> None:
    """Run the engine's start (or the publisher's first publication) here and print what it cost and kept.
    ``reads``: the engine's read transactions (None: the board worker's own connections, as deployed)."""
    worker = worker_for_url(url, DATASETS, SETTINGS)
    before = resident_mb()
    if trace:
        tracemalloc.start()
    cpu, wall = time.process_time(), time.perf_counter()
    usage = resource.getrusage(resource.RUSAGE_SELF)
    if publish:
        worker.publisher.publish("private")
    else:
        BoardEngine(reads or worker.publisher.read, DATASETS, SETTINGS).update("private")
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    what = "the publisher's first publication" if publish else "the engine's start"
    after = resource.getrusage(resource.RUSAGE_SELF)
    user, system = after.ru_utime - usage.ru_utime, after.ru_stime - usage.ru_stime
    print(f"{what}: {wall:.1f} s, {cpu:.1f} s CPU ({user:.1f} user + {system:.1f} system)")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"resident: {before:.0f} MB before, {resident_mb():.0f} MB after (peak {peak:.0f} MB)", flush=True)
    if not trace:
        return
    snapshot = tracemalloc.take_snapshot()
    tracemalloc.stop()
    lines = snapshot.statistics("lineno")
    print(f"traced, alive: {sum(s.size for s in lines) / 2**20:.1f} MB")
    for stat in lines[:top]:
        frame = stat.traceback[0]
        where = f"{Path(frame.filename).name}:{frame.lineno}"
        print(f"  {stat.size / 2**20:8.1f} MB  {stat.count:9,d} objects  {where}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--database-url", required=True)
    parser.add_argument("--top", type=int, default=15, help="allocation sites to list")
    parser.add_argument("--no-trace", action="store_true", help="resident memory and CPU only")
    parser.add_argument("--publish", action="store_true", help="the publisher's first publication")
    parser.add_argument(
        "--own-process", action="store_true", help="in a process with only the board worker's imports"
    )
    args = parser.parse_args()

    # the server's modules only here: a spawned measuring process imports this file again, not them
    from bench_server import bench_settings

    from robobpp.server.bootstrap import bootstrap
    from robobpp.server.runtime import Runtime

    runtime = Runtime(bench_settings(args.database_url, Path(tempfile.mkdtemp(prefix="robobpp-memory-"))))
    bootstrap(runtime)
    if args.own_process:
        runtime.dispose()
        child = multiprocessing.get_context("spawn").Process(
            target=measure, args=(args.database_url, args.publish, not args.no_trace, args.top)
        )
        child.start()
        child.join()
        raise SystemExit(child.exitcode)
    measure(args.database_url, args.publish, not args.no_trace, args.top, runtime.read_session)
    runtime.dispose()


if __name__ == "__main__":
    main()
