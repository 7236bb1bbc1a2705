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
* ``visible_after_s``: from the submission's commit to its boards computed by the engine (wall);
* with ``--lookahead-entries N``: N of the seeded submissions made with lookahead 10 (boards of their own,
  docs/server.md, "Boards per lookahead") before the engine starts, and ``recompute_lookahead_cpu_s``: one more
  finished lookahead-10 submission (its boards and grid only);
* with ``--served``, end to end as a user meets it: the server runs for real (a subprocess as in
  ``bench_server.py``, its board worker publishing to SQL), and ``served_visible_after_s`` is the wall time
  from a finished submission's commit until every board route of the API (15 boards: closed loop and the
  paper protocol) shows it (``served_published_after_s``: until the worker's publication of it landed, the
  rest is the API noticing it and reading the new version); ``api_rss_mb`` is the API process's resident memory after that,
  ``board_worker_rss_mb`` its board worker's.

    python bench/bench_boards.py --submissions 10000 --database-url URL --json FILE [--reuse] [--served]
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
from _common import machine
from bench_server import bench_settings, children, seed_rows, start_server
from bench_server import rss_mb as process_rss_mb
from sqlalchemy import text

from robobpp.boards.engine import BoardEngine, compute_snapshot
from robobpp.server.bootstrap import bootstrap
from robobpp.server.runtime import Runtime
from robobpp.vocabulary import CLOSED, DATASETS, LOOPS, PHYSICAL, SETTINGS


def timed(fn: Any) -> tuple[Any, float, float]:
    """(result, wall s, CPU s of this process)."""
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def resident_mb() -> float:
    """This process's resident memory now (Linux; its peak elsewhere)."""
    try:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) / 1024 for line in status if line.startswith("VmRSS"))
    except (OSError, StopIteration):
        return rss_mb()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--database-url", default="")
    parser.add_argument("--submissions", type=int, default=10_000)
    parser.add_argument("--json", default="", help="write the figures here")
    parser.add_argument("--reuse", action="store_true", help="the database is already seeded")
    parser.add_argument("--skip-before", action="store_true", help="do not time the full recompute")
    parser.add_argument("--seed-only", action="store_true", help="seed the database and stop")
    parser.add_argument("--skip-refresh", action="store_true", help="do not time the refresh")
    parser.add_argument(
        "--lookahead-entries", type=int, default=0, help="this many seeded submissions saw 10 next boxes"
    )
    parser.add_argument(
        "--served", action="store_true", help="only the end-to-end figures, through a real server and its API"
    )
    args = parser.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="robobpp-bench-boards-"))
    url = args.database_url or f"sqlite:///{tmp / 'bench.sqlite3'}"
    runtime = Runtime(bench_settings(url, tmp))
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
    if args.served:
        figures |= served_figures(runtime, url, count, tmp)
        runtime.dispose()
        if args.json:
            Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")
        return

    if not args.skip_before:
        with runtime.read_session() as s:
            _, wall, cpu = timed(lambda: compute_snapshot(s, DATASETS, SETTINGS, "private"))
        figures["before_cpu_s"], figures["before_wall_s"] = round(cpu, 2), round(wall, 2)
        print(f"before: full recompute of the track {wall:.1f} s ({cpu:.1f} s CPU)")

    if args.lookahead_entries:
        with runtime.session() as s:  # spread over the seeded ones (their quality is drawn)
            step = max(1, count // args.lookahead_entries)
            s.execute(
                text(
                    "UPDATE submissions SET lookahead = 10 WHERE id IN (SELECT id FROM submissions WHERE id % :step = 3 ORDER BY id LIMIT :n)"
                ),
                {"step": step, "n": args.lookahead_entries},
            )
        figures["lookahead_entries"] = args.lookahead_entries
    engine = BoardEngine(runtime.read_session, DATASETS, SETTINGS)
    _, wall, cpu = timed(lambda: engine.update("private"))
    figures["engine_start_cpu_s"], figures["engine_start_wall_s"] = round(cpu, 2), round(wall, 2)
    figures["engine_rss_mb"], figures["engine_peak_rss_mb"] = round(resident_mb()), round(rss_mb())
    print(f"engine start (full, every rank interval): {wall:.1f} s ({cpu:.1f} s CPU)")
    print(f"  RSS after it {figures['engine_rss_mb']} MB, peak {figures['engine_peak_rss_mb']} MB")

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
    if args.lookahead_entries:
        while count % 50 in (7, 23):
            seed_rows(runtime, 1, first=count)
            count += 1
            engine.update("private")
        seed_rows(runtime, 1, first=count, fixed_quality=0.5)
        count += 1
        with runtime.session() as s:
            s.execute(
                text("UPDATE submissions SET lookahead = 10 WHERE id = (SELECT max(id) FROM submissions)")
            )
        changed, wall, cpu = timed(lambda: engine.update("private"))
        figures["recompute_lookahead_cpu_s"] = round(cpu, 3)
        figures["boards_changed_lookahead"] = len(changed)
        print(
            f"one finished lookahead-10 submission: {len(changed)} boards and grids updated in {wall:.2f} s ({cpu:.2f} s CPU)"
        )
    if not args.skip_refresh:
        _, wall, cpu = timed(lambda: engine.refresh("private"))
        figures["refresh_cpu_s"], figures["refresh_wall_s"] = round(cpu, 2), round(wall, 2)
        figures["refresh_rss_mb"] = round(resident_mb())
        print(f"refresh (full, every rank interval): {wall:.1f} s ({cpu:.1f} s CPU)")
        print(f"  RSS after it {figures['refresh_rss_mb']} MB, peak {rss_mb():.0f} MB")
    figures["peak_rss_mb"] = round(rss_mb(), 0)  # of this process: the full recompute's, unless skipped
    figures["api_rss_mb"] = None  # the API process reads published boards: measured with the publication side
    print(f"peak RSS of this process {figures['peak_rss_mb']:.0f} MB")
    runtime.dispose()
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")


def board_paths(submission_id: int) -> list[str]:
    """Every board route of the API, asked for one submission's entry (all entries, not only the best)."""
    return [
        f"/api/v1/leaderboards/{d}/{st}?view=all&submission={submission_id}&protocol={protocol}"
        for d in DATASETS
        for st in SETTINGS
        for protocol in (LOOPS if st in PHYSICAL else (CLOSED,))
    ]


def wait_visible(client: httpx.Client, submission_id: int, deadline_s: float) -> float:
    """Seconds until every board route shows ``submission_id`` (a route that shows it keeps showing it)."""
    start, end = time.perf_counter(), time.monotonic() + deadline_s
    waiting = board_paths(submission_id)
    while waiting:
        if time.monotonic() > end:
            raise RuntimeError(f"not on {len(waiting)} board routes after {deadline_s:.0f} s: {waiting[0]}")
        r = client.get(waiting[0])
        if r.status_code == 200 and any(e["submission_id"] == submission_id for e in r.json()["entries"]):
            waiting.pop(0)
        elif r.status_code not in (200, 503):  # 503: nothing published yet
            raise RuntimeError(f"{waiting[0]}: {r.status_code} {r.text[:300]}")
        else:
            time.sleep(0.05)
    return time.perf_counter() - start


def published_version(runtime: Runtime) -> int:
    """The private track's publication version (boards/store.py): moves when the worker writes it."""
    with runtime.read_session() as s:
        return int(
            s.execute(text("SELECT version FROM board_publications WHERE track = 'private'")).scalar_one()
        )


def newest(runtime: Runtime) -> int:
    with runtime.read_session() as s:
        return int(s.execute(text("SELECT max(id) FROM submissions")).scalar_one())


def served_figures(runtime: Runtime, url: str, count: int, state: Path) -> dict[str, Any]:
    """End to end: a real server publishes; a finished submission is timed until every board route shows it."""
    proc, base = start_server(url, state, 1)
    out: dict[str, Any] = {}
    try:
        with httpx.Client(base_url=base, timeout=60) as client:
            # a first submission, waited for: the worker's start-up computation is over once it is everywhere
            while count % 50 in (7, 23):  # bench_server makes these failed or partial
                seed_rows(runtime, 1, first=count)
                count += 1
            seed_rows(runtime, 1, first=count, fixed_quality=0.5)
            first = wait_visible(client, newest(runtime), deadline_s=3600)
            print(f"server up, boards published, a first submission visible after {first:.1f} s")
            count += 1
            for label, quality in (("", 0.5), ("_best", 1.0)):
                while count % 50 in (7, 23):
                    seed_rows(runtime, 1, first=count)
                    count += 1
                version = published_version(runtime)
                seed_rows(runtime, 1, first=count, fixed_quality=quality)
                committed = time.perf_counter()
                while published_version(runtime) == version:  # the worker's part: noticed, computed, written
                    time.sleep(0.02)
                published = time.perf_counter() - committed
                visible = published + wait_visible(client, newest(runtime), deadline_s=600)
                count += 1
                out[f"served_published_after{label}_s"] = round(published, 2)
                out[f"served_visible_after{label}_s"] = round(visible, 2)
                print(
                    f"finished submission (quality {quality}) published after {published:.2f} s, on every board "
                    f"route after {visible:.2f} s"
                )
        out["api_rss_mb"] = round(process_rss_mb(proc.pid))
        out["board_worker_rss_mb"] = [round(process_rss_mb(c)) for c in children(proc.pid)]
        print(f"RSS: API process {out['api_rss_mb']} MB, its children {out['board_worker_rss_mb']} MB")
    finally:
        proc.terminate()
        proc.wait(30)
    return out


if __name__ == "__main__":
    main()
