"""Board updates at scale: what one finished submission costs the boards, and how soon it is on them.

Seeds the database as ``bench_server.py`` does (N finished submissions, their runs with per-group figures
and stored scoring parts, as a worker writes them), then:

* ``before_cpu_s``: the full recompute of a track's fifteen boards and two grids (``compute_snapshot``:
  what every finished submission cost before the board engine), once;
* ``engine_start_cpu_s``: the engine's first, full computation (every rank interval included: what the
  board worker does at start and on its refresh timer, ``refresh_cpu_s`` measures it again warm);
* ``recompute_cpu_s``: one more finished submission of middling quality — ``BoardEngine.update`` of its
  track (the boards it is on, and the grids), CPU of this process; ``recompute_best_cpu_s``: one that is a
  new best (it moves the normalisation of every board: every entry renormalised);
* ``visible_after_s``: from the submission's commit to its boards computed by the engine (wall).

    python bench/bench_boards.py --submissions 10000 --database-url URL --json FILE [--reuse]
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path
from typing import Any

from _common import machine
from bench_server import GROUPS, SETTINGS, seed_rows
from sqlalchemy import text

from robobpp.server.bootstrap import bootstrap
from robobpp.server.config import Settings
from robobpp.server.runtime import Runtime
from robobpp.server.services.board_engine import BoardEngine, compute_snapshot

DATASETS = ("repetitive", "diverse", "longboard")


def timed(fn: Any) -> tuple[Any, float, float]:
    """(result, wall s, CPU s of this process)."""
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--database-url", default="")
    parser.add_argument("--submissions", type=int, default=10_000)
    parser.add_argument("--json", default="", help="write the figures here")
    parser.add_argument("--reuse", action="store_true", help="the database is already seeded")
    parser.add_argument("--skip-before", action="store_true", help="do not time the full recompute")
    parser.add_argument("--seed-only", action="store_true", help="seed the database and stop")
    parser.add_argument("--skip-refresh", action="store_true", help="do not time the refresh")
    args = parser.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="robobpp-bench-boards-"))
    url = args.database_url or f"sqlite:///{tmp / 'bench.sqlite3'}"
    runtime = Runtime(
        Settings(
            database_url=url,
            state_dir=tmp,
            workers=0,
            evaluate_baselines=False,
            settings=SETTINGS,
            groups=GROUPS,
            spec_provider="robobpp.worker.specs:offline_spec",
        )
    )
    bootstrap(runtime)
    figures: dict[str, Any] = {"machine": machine()}
    if not args.reuse:
        _, wall, _ = timed(lambda: seed_rows(runtime, args.submissions))
        figures["seed_s"] = round(wall, 1)
    with runtime.read_session() as s:
        count = s.execute(text("SELECT count(*) FROM submissions")).scalar_one()
    figures["database"] = runtime.engine.url.get_backend_name()
    figures["submissions"] = count
    print(f"{count:,} submissions; {figures['database']}; {machine()}")
    if args.seed_only:
        runtime.dispose()
        return

    if not args.skip_before:
        with runtime.read_session() as s:
            _, wall, cpu = timed(lambda: compute_snapshot(s, DATASETS, SETTINGS, "private"))
        figures["before_cpu_s"], figures["before_wall_s"] = round(cpu, 2), round(wall, 2)
        print(f"before: full recompute of the track {wall:.1f} s ({cpu:.1f} s CPU)")

    engine = BoardEngine(runtime.read_session, DATASETS, SETTINGS)
    _, wall, cpu = timed(lambda: engine.update("private"))
    figures["engine_start_cpu_s"], figures["engine_start_wall_s"] = round(cpu, 2), round(wall, 2)
    print(f"engine start (full, every rank interval): {wall:.1f} s ({cpu:.1f} s CPU)")

    for label, quality in (("", 0.5), ("_best", 1.0)):
        while count % 50 in (7, 23):  # bench_server makes these failed or partial: one on every board, timed
            seed_rows(runtime, 1, first=count)
            count += 1
            engine.update("private")
        seed_rows(runtime, 1, first=count, fixed_quality=quality)
        count += 1
        committed = time.perf_counter()
        changed, wall, cpu = timed(lambda: engine.update("private"))
        visible = time.perf_counter() - committed
        figures[f"recompute{label}_cpu_s"] = round(cpu, 3)
        figures[f"visible_after{label}_s"] = round(visible, 3)
        figures[f"boards_changed{label}"] = len(changed)
        print(
            f"one finished submission (quality {quality}): {len(changed)} boards and grids updated in "
            f"{wall:.2f} s ({cpu:.2f} s CPU)"
        )
    if not args.skip_refresh:
        _, wall, cpu = timed(lambda: engine.refresh("private"))
        figures["refresh_cpu_s"], figures["refresh_wall_s"] = round(cpu, 2), round(wall, 2)
        print(f"refresh (full, every rank interval): {wall:.1f} s ({cpu:.1f} s CPU)")
    figures["peak_rss_mb"] = round(rss_mb(), 0)  # of this process: the full recompute's, unless skipped
    figures["api_rss_mb"] = None  # the API process reads published boards: measured with the publication side
    print(f"peak RSS of this process {figures['peak_rss_mb']:.0f} MB")
    runtime.dispose()
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")


if __name__ == "__main__":
    main()
