"""Evaluation server at scale: every page and API route under 20 concurrent readers, with 10,000 submissions
(147,600 runs, 4.4 M episode rows: each submission with Math Pack also has Physics and Execution under the
paper protocol, as the server creates them) in the database, and submissions accepted per second.

The server runs for real in a subprocess (uvicorn, ``--server-workers`` processes — one, as ``robobpp serve``
runs it — no evaluation workers); the readers are a separate load-generator process (``_load.py``) over
loopback HTTP, each issuing its next request as soon as the last one answered (closed loop, no think time),
round-robin over every page and API route (``routes``). It prints p50/p95 per route, the server's CPU per
request under load, and per route alone (one request at a time: the server's CPU, the PostgreSQL backends'
CPU and the wall time per request), the load generator's CPU and the API process's RSS. The database is
seeded in bulk by ``_seed.py`` (PostgreSQL ``COPY``, SQLite ``executemany``): figures random but fixed by
a seed, each run's aggregate, per-group figures and stored scoring part what a worker stores for its
episodes (checked against the worker's functions as it seeds). 2 % of the submissions are failed (every
episode a policy error) and 2 % partial (Math Pack only), as on a real board. ``--add`` grows a seeded
database (a copy: ``createdb -T``) by ``--submissions`` more.

    python bench/bench_server.py [--database-url URL] [--submissions 10000] [--readers 20] [--samples 60]
        [--seed-only | --reuse [--cold]] [--add] [--episodes-every 1] [--only REGEX] [--accepts 40] [--state-dir DIR]
        [--board-worker process|off]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import httpx
from _common import machine, median, percentile
from _load import read_concurrently
from _seed import GROUPS, seed
from pydantic import SecretStr
from sqlalchemy import text

from robobpp.boards.engine import leaderboard
from robobpp.boards.ranking import build_grid
from robobpp.client.serve import BackgroundServer, create_policy_app
from robobpp.policies.dbl import DBL
from robobpp.server.app import create_app
from robobpp.server.bootstrap import bootstrap
from robobpp.server.config import Settings
from robobpp.vocabulary import DATASETS, SETTINGS

ADMIN = "bench-admin-token-0123456789abcdef"


def bench_settings(url: str, state_dir: Path) -> Settings:
    """The server settings every bench's database is seeded and read with (the nine boards, 30 groups, no
    workers, no baselines; the offline spec provider, so no dataset download is needed)."""
    return Settings(
        database_url=url,
        state_dir=state_dir,
        admin_token=SecretStr(ADMIN),
        workers=0,
        evaluate_baselines=False,
        settings=SETTINGS,
        groups=GROUPS,
        spec_provider="robobpp.worker.specs:offline_spec",
    )


def seed_rows(
    runtime: Any, n: int, *, first: int = 0, fixed_quality: float | None = None, episodes_every: int = 1
) -> int:
    """Insert ``n`` finished submissions with their runs and episodes (``_seed.seed``); returns the episode
    rows written. ``first``: how many the database already has (these are its next ones, finishing now);
    ``fixed_quality``: theirs (0..1; default: drawn), e.g. 1 for a new best; ``episodes_every``: episode rows
    for one submission in that many (and the newest 1,000)."""
    return seed(runtime, n, first=first, fixed_quality=fixed_quality, episodes_every=episodes_every).episodes


def routes(sid: int, cookie: str, episode_id: int) -> list[tuple[str, str, dict[str, str]]]:
    """(label, path, headers) of every page and API route a reader uses: public pages anonymous (as a
    visitor reads them), a submission's own page signed in (its owner's view; here the operator's), the
    API with a bearer token."""
    api = {"Authorization": f"Bearer {ADMIN}"}
    anonymous: dict[str, str] = {}
    owner = {"Cookie": cookie}
    return [
        ("GET / (home: overall grid, best entries)", "/", anonymous),
        ("GET /?view=all&page=100", "/?view=all&page=100", anonymous),
        ("GET /boards/diverse/math", "/boards/diverse/math", anonymous),
        ("GET /?protocol=paper (grid under the paper protocol)", "/?protocol=paper", anonymous),
        ("GET /boards/diverse/physics?protocol=paper", "/boards/diverse/physics?protocol=paper", anonymous),
        ("GET /reproduction", "/reproduction", anonymous),
        (
            "GET /boards/repetitive/execution?view=all&page=50",
            "/boards/repetitive/execution?view=all&page=50",
            anonymous,
        ),
        ("GET /submissions/{id} (page, signed in)", f"/submissions/{sid}", owner),
        ("GET /submissions/{id}/status.json (signed in)", f"/submissions/{sid}/status.json", owner),
        ("GET /account (signed in: all submissions, newest 50)", "/account", owner),
        ("GET /operator (signed in)", "/operator", owner),
        ("GET /datasets", "/datasets", anonymous),
        ("GET /protocol", "/protocol", anonymous),
        ("GET /docs", "/docs", anonymous),
        ("GET /openapi.json", "/openapi.json", anonymous),
        ("GET /api/v1/leaderboards (grid)", "/api/v1/leaderboards", api),
        ("GET /api/v1/leaderboards?view=all&offset=5000", "/api/v1/leaderboards?view=all&offset=5000", api),
        ("GET /api/v1/leaderboards/diverse/math", "/api/v1/leaderboards/diverse/math", api),
        (
            "GET /api/v1/leaderboards/longboard/execution?protocol=paper",
            "/api/v1/leaderboards/longboard/execution?protocol=paper",
            api,
        ),
        (
            "GET /api/v1/leaderboards/longboard/physics?view=all&offset=9000",
            "/api/v1/leaderboards/longboard/physics?view=all&offset=9000",
            api,
        ),
        (
            "GET /api/v1/leaderboards/repetitive/execution?submission={id}",
            f"/api/v1/leaderboards/repetitive/execution?view=all&submission={sid}",
            api,
        ),
        ("GET /api/v1/submissions/{id}", f"/api/v1/submissions/{sid}", api),
        ("GET /api/v1/submissions/{id}/episodes", f"/api/v1/submissions/{sid}/episodes", api),
        (
            "GET /api/v1/submissions/{id}/episodes/{episode_id}",
            f"/api/v1/submissions/{sid}/episodes/{episode_id}",
            api,
        ),
        ("GET /api/v1/submissions (list)", "/api/v1/submissions", api),
        ("GET /api/v1/me", "/api/v1/me", api),
        ("GET /api/v1/info", "/api/v1/info", api),
        ("GET /healthz", "/healthz", anonymous),
        ("GET /metrics", "/metrics", api),  # the operator's (ROBOBPP_METRICS_PUBLIC opens it)
    ]


def sign_in(base: str) -> str:
    """The operator's session cookie, through the sign-in form as a browser gets it."""
    with httpx.Client(base_url=base, timeout=60) as client:
        page = client.get("/sign-in").text
        csrf = re.search(r'name="csrf" value="([^"]+)"', page)
        assert csrf is not None, "no CSRF field on the sign-in page"
        client.post("/sign-in", data={"token": ADMIN, "csrf": csrf.group(1)})
        value = client.cookies.get("robobpp_session")
        assert value, "signing in set no session cookie"
        return f"robobpp_session={value}"


def cpu_seconds(pid: int) -> float:
    """User + system CPU of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rss_mb(pid: int) -> float:
    """Resident memory of a process now, MB (Linux /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def children(pid: int) -> list[int]:
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        out += [int(c) for c in (task / "children").read_text().split()]
    return out


def cpu_per_request(
    base: str, pid: int, paths: list[tuple[str, str, dict[str, str]]], n: int, database: Any = None
) -> dict[str, tuple[float, float, float]]:
    """Each route alone, one request at a time (no queueing), ``n`` requests each: (server CPU per request,
    median wall time per request, PostgreSQL backends' CPU per request — NaN unless ``database``, an engine
    of a local PostgreSQL server, is given)."""
    out = {}
    with httpx.Client(base_url=base, timeout=60) as client:
        for label, path, headers in paths:
            client.get(path, headers=headers)
            backends = _backends(database)
            c0, d0 = cpu_seconds(pid), _cpu_of(backends)
            walls = []
            for _ in range(n):
                t0 = time.perf_counter()
                client.get(path, headers=headers)
                walls.append(time.perf_counter() - t0)
            out[label] = ((cpu_seconds(pid) - c0) / n, median(walls), (_cpu_of(backends) - d0) / n)
    return out


def _backends(database: Any) -> list[int]:
    """The PostgreSQL backends serving the benchmarked database (other than this query's), when local."""
    if database is None or database.dialect.name != "postgresql":
        return []
    with database.connect() as c:
        return [
            int(p)
            for (p,) in c.execute(
                text(
                    "SELECT pid FROM pg_stat_activity WHERE datname = current_database() "
                    "AND pid <> pg_backend_pid() AND backend_type = 'client backend'"
                )
            )
        ]


def _cpu_of(pids: list[int]) -> float:
    if not pids:
        return float("nan")
    total = 0.0
    for p in pids:
        with contextlib.suppress(OSError):  # a backend that ended
            total += cpu_seconds(p)
    return total


def start_server(
    url: str, state: Path, workers: int, board_worker: str = "process"
) -> tuple[subprocess.Popen[bytes], str]:
    """``board_worker``: ``off`` serves the boards already published in SQL and computes none (a restarted
    server's worker otherwise builds its state for the updates first: at 100,000 submissions minutes of a core
    beside the readers)."""
    env = {
        **os.environ,
        "ROBOBPP_DATABASE_URL": url,
        "ROBOBPP_STATE_DIR": str(state),
        "ROBOBPP_ADMIN_TOKEN": ADMIN,
        "ROBOBPP_WORKERS": "0",
        "ROBOBPP_EVALUATE_BASELINES": "0",
        "ROBOBPP_SETTINGS": json.dumps(list(SETTINGS)),
        "ROBOBPP_GROUPS": str(GROUPS),
        "ROBOBPP_ALLOW_PRIVATE_POLICY_URLS": "1",
        "ROBOBPP_QUOTA_CONCURRENT": "1000000",
        "ROBOBPP_QUOTA_SUBMISSIONS_PER_DAY": "1000000",
        "ROBOBPP_SPEC_PROVIDER": "robobpp.worker.specs:offline_spec",
        "ROBOBPP_BOARD_WORKER": board_worker,
    }
    port = _free_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "uvicorn",
            "robobpp.server.app:create_app",
            "--factory",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--workers",
            str(workers),
            "--log-level",
            "warning",
            "--no-access-log",
        ],
        env=env,
    )
    base = f"http://127.0.0.1:{port}"
    for _ in range(600):
        try:
            if httpx.get(f"{base}/api/v1/info", timeout=2).status_code == 200:
                return proc, base
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    proc.terminate()
    raise RuntimeError("the server did not start")


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def warm_up(
    base: str, paths: list[tuple[str, str, dict[str, str]]], limit_s: float = 0.5, deadline_s: float = 1800
) -> None:
    """Until a whole pass answers each request within ``limit_s``: the board worker has published the boards
    (before its first publication a board route answers 503) and the pages were rendered once."""
    end = time.monotonic() + deadline_s
    with httpx.Client(base_url=base, timeout=deadline_s) as client:
        while time.monotonic() < end:
            slowest = 0.0
            for _label, path, headers in paths:
                t0 = time.perf_counter()
                r = client.get(path, headers=headers)
                if r.status_code == 503:  # not published yet: this pass does not count
                    slowest = limit_s
                    time.sleep(0.5)
                    break
                if r.status_code != 200:
                    raise RuntimeError(f"{path}: {r.status_code} {r.text[:300]}")
                slowest = max(slowest, time.perf_counter() - t0)
            if slowest < limit_s:
                return
    raise RuntimeError("the server did not warm up")


def accepts_per_second(client: httpx.Client, body: dict[str, Any], n: int, threads: int) -> float:
    errors: list[str] = []

    def post(k: int) -> None:
        for _ in range(k):
            r = client.post("/api/v1/submissions", json=body)
            if r.status_code != 201:
                errors.append(r.text)

    per = n // threads
    workers = [threading.Thread(target=post, args=(per,)) for _ in range(threads)]
    t0 = time.perf_counter()
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    elapsed = time.perf_counter() - t0
    if errors:
        raise RuntimeError(errors[0])
    return per * threads / elapsed


def cold_figures(runtime: Any) -> list[tuple[str, float, float]]:
    """What a change of the board costs once: (label, wall s, CPU s) of each board and the grid, computed
    as the server computes them (in the background; readers keep the previous version meanwhile)."""
    out = []
    with runtime.read_session() as s:
        boards = {}
        for st in SETTINGS:
            for d in DATASETS:
                t0, c0 = time.perf_counter(), time.process_time()
                boards[f"{st}/{d}"] = leaderboard(s, d, st)
                out.append(
                    (
                        f"board {st}/{d} ({len(boards[f'{st}/{d}'].entries)} ranked)",
                        time.perf_counter() - t0,
                        time.process_time() - c0,
                    )
                )
        t0, c0 = time.perf_counter(), time.process_time()
        build_grid(boards, DATASETS, SETTINGS, "private")
        out.append(("overall grid from the nine boards", time.perf_counter() - t0, time.process_time() - c0))
        for st in SETTINGS[1:]:  # the physical boards again, under the paper protocol
            for d in DATASETS:
                t0, c0 = time.perf_counter(), time.process_time()
                boards[f"{st}/{d}"] = leaderboard(s, d, st, loop="paper")
                out.append(
                    (
                        f"board {st}/{d}, paper protocol ({len(boards[f'{st}/{d}'].entries)} ranked)",
                        time.perf_counter() - t0,
                        time.process_time() - c0,
                    )
                )
        t0, c0 = time.perf_counter(), time.process_time()
        build_grid(boards, DATASETS, SETTINGS, "private")
        out.append(
            ("overall grid under the paper protocol", time.perf_counter() - t0, time.process_time() - c0)
        )
    return out


def _ms(values: list[float]) -> str:
    """p50 | p95 | p99 | max, in ms: the tail shows pauses (a garbage collection) that p95 can hide."""
    return " | ".join(
        f"{x * 1e3:.1f}"
        for x in (median(values), percentile(values, 95), percentile(values, 99), max(values))
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--database-url", default="")
    parser.add_argument("--submissions", type=int, default=10_000)
    parser.add_argument("--readers", type=int, default=20)
    parser.add_argument("--samples", type=int, default=60, help="requests per route")
    # one process, as ``robobpp serve`` runs it
    parser.add_argument("--server-workers", type=int, default=1)
    parser.add_argument("--reuse", action="store_true", help="the database is already seeded")
    parser.add_argument("--seed-only", action="store_true", help="seed the database and stop")
    parser.add_argument(
        "--add",
        action="store_true",
        help="seed --submissions more after those the database has (e.g. grow a copy of a seeded one)",
    )
    parser.add_argument(
        "--episodes-every",
        type=int,
        default=1,
        help="episode rows for one submission in this many (and the newest 1,000); runs are always all written",
    )
    parser.add_argument(
        "--cold", action="store_true", help="time the cold computation (default unless --reuse)"
    )
    parser.add_argument("--accepts", type=int, default=40)
    parser.add_argument(
        "--only",
        default="",
        help="only the routes whose label matches this regular expression (default: all)",
    )
    parser.add_argument(
        "--board-worker",
        choices=("process", "off"),
        default="process",
        help="off: read the boards already published (--reuse), the board worker not building its state meanwhile",
    )
    parser.add_argument(
        "--state-dir",
        default="",
        help="the server's state directory (default: a new one); "
        "reused, it holds the boards the last run stored, served at once after a restart",
    )
    args = parser.parse_args()

    tmp = Path(args.state_dir) if args.state_dir else Path(tempfile.mkdtemp(prefix="robobpp-bench-"))
    tmp.mkdir(parents=True, exist_ok=True)
    url = args.database_url or f"sqlite:///{tmp / 'bench.sqlite3'}"
    app = create_app(bench_settings(url, tmp), start_workers=False)
    runtime = app.state.runtime
    bootstrap(runtime)
    seeded = "reused"
    if not args.reuse:
        with runtime.read_session() as s:
            have = s.execute(text("SELECT count(*) FROM submissions")).scalar_one() if args.add else 0
        load = os.getloadavg()[0]
        st = seed(runtime, args.submissions, first=have, episodes_every=args.episodes_every)
        seeded = (
            f"seeded {st.submissions:,} submissions, {st.runs:,} runs, {st.episodes:,} episodes in {st.wall_s:.0f} s: "
            f"{st.rows / st.wall_s:,.0f} rows/s; CPU {st.cpu_s:.0f} s (generating {st.generate_cpu_s:.0f} s), writing {st.write_s:.0f} s "
            f"(database CPU {st.database_cpu_s or float('nan'):.0f} s), generator waiting for the writer "
            f"{st.write_wait_s:.0f} s; load average {load:.1f} before, {os.getloadavg()[0]:.1f} after; "
            f"{st.checked} runs checked against the worker's functions"
        )
    with runtime.read_session() as s:
        n_subs = s.execute(text("SELECT count(*) FROM submissions")).scalar_one()
        n_waiting = s.execute(text("SELECT count(*) FROM submissions WHERE finished_at IS NULL")).scalar_one()
        n_eps = s.execute(text("SELECT count(*) FROM episodes")).scalar_one()
        # the middle submission (a complete one) with episode rows (``--episodes-every``: not all have them)
        middle = s.execute(
            text("SELECT id FROM submissions ORDER BY id LIMIT 1 OFFSET :k"), {"k": n_subs // 2}
        )
        sid = s.execute(
            text("SELECT min(submission_id) FROM episodes WHERE submission_id >= :m"),
            {"m": middle.scalar_one()},
        ).scalar_one()
        episode_id = s.execute(
            text("SELECT min(id) FROM episodes WHERE submission_id = :s"), {"s": sid}
        ).scalar_one()
    print(
        f"{n_subs:,} submissions ({n_waiting:,} not finished), {n_eps:,} episode rows ({seeded}); database: "
        f"{runtime.engine.url.get_backend_name()}; {machine()}"
    )
    if args.seed_only:
        runtime.dispose()
        return
    if args.cold or not args.reuse:
        print(f"cold computation (load average {os.getloadavg()[0]:.1f}):")
        for label, wall, cpu in cold_figures(runtime):
            print(f"- {label}: {wall:.1f} s ({cpu:.1f} s CPU)")

    proc, base = start_server(url, tmp, args.server_workers, args.board_worker)
    try:
        paths = [r for r in routes(sid, sign_in(base), episode_id) if re.search(args.only, r[0])]
        t0 = time.perf_counter()
        warm_up(base, paths)
        scrape = httpx.get(f"{base}/metrics", headers={"Authorization": f"Bearer {ADMIN}"}).text
        snapshot = re.search(
            r'^robobpp_board_publication_seconds\{track="private"\} ([0-9.e+-]+)$', scrape, re.M
        )
        print(
            f"warm-up (the server serves the boards published in SQL at once; when none is current, its board "
            f"worker computes each track's fifteen boards and two grids first): "
            f"{time.perf_counter() - t0:.0f} s; last publication "
            f"{float(snapshot.group(1)) if snapshot else float('nan'):.1f} s"
        )
        alone = cpu_per_request(base, proc.pid, paths, 50, runtime.engine)
        load0 = os.getloadavg()[0]
        server0 = cpu_seconds(proc.pid)
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            result = pool.submit(read_concurrently, base, paths, args.readers, args.samples).result()
        server_cpu = cpu_seconds(proc.pid) - server0
        if result["error_count"]:
            raise RuntimeError(f"{result['error_count']} failed requests, e.g. {result['errors']}")
        samples: dict[str, list[float]] = result["latencies"]
        total = sum(len(v) for v in samples.values())
        elapsed = result["elapsed"]
        print(
            f"\n{args.readers} concurrent readers (one load-generator process), {args.server_workers} server "
            f"process(es): {total} requests in {elapsed:.1f} s ({total / elapsed:.0f} per second); server CPU "
            f"{server_cpu:.1f} s ({1e3 * server_cpu / total:.2f} ms per request), load generator CPU "
            f"{result['cpu']:.1f} s ({1e3 * result['cpu'] / total:.2f} ms per request); load average "
            f"{load0:.1f} before, {os.getloadavg()[0]:.1f} after"
        )
        with httpx.Client(base_url=base, timeout=60) as client:
            sizes = {label: len(client.get(path, headers=headers).content) for label, path, headers in paths}
        print(
            "\n| route | n | p50 (ms) | p95 (ms) | p99 (ms) | max (ms) | alone: server CPU (ms) | alone: "
            "PostgreSQL CPU (ms) | alone: wall p50 (ms) | body (kB) |\n|---|---|---|---|---|---|---|---|---|---|"
        )
        for label, values in samples.items():
            print(
                f"| {label} | {len(values)} | {_ms(values)} | {alone[label][0] * 1e3:.1f} | "
                f"{alone[label][2] * 1e3:.1f} | {alone[label][1] * 1e3:.1f} | {sizes[label] / 1e3:.1f} |"
            )
        everything = [v for values in samples.values() for v in values]
        print(f"| all routes | {len(everything)} | {_ms(everything)} | | | | |")
        others = ", ".join(f"{rss_mb(c):.0f} MB" for c in children(proc.pid))
        print(
            f"\nRSS after the readers: server process {rss_mb(proc.pid):.0f} MB; its children {others or 'none'}"
        )

        if args.accepts:
            with httpx.Client(
                base_url=base, timeout=60, headers={"Authorization": f"Bearer {ADMIN}"}
            ) as client:
                builtin = {"name": "bench", "policy_url": "builtin:dbl"}
                rate_builtin = accepts_per_second(client, builtin, args.accepts, 1)
                rate_builtin_4 = accepts_per_second(client, builtin, args.accepts, 4)
                with BackgroundServer(create_policy_app(DBL, "bench-secret-123")) as policy:
                    remote = {"name": "bench", "policy_url": policy.url, "secret": "bench-secret-123"}
                    rate_remote = accepts_per_second(client, remote, args.accepts, 1)
            print("\n| submission | clients | accepted per second |\n|---|---|---|")
            print(
                f"| builtin policy (no URL probe), 450 episode rows each (270 closed loop, 180 paper protocol) | 1 | {rate_builtin:.1f} |"
            )
            print(
                f"| builtin policy (no URL probe), 450 episode rows each (270 closed loop, 180 paper protocol) | 4 | {rate_builtin_4:.1f} |"
            )
            print(
                f"| policy URL (resolve, pin, signed GET /info), 450 episode rows each (270 closed loop, 180 paper protocol) | 1 | {rate_remote:.1f} |"
            )
    finally:
        proc.terminate()
        proc.wait(30)
        runtime.dispose()


if __name__ == "__main__":
    main()
