"""Evaluation server: leaderboard API latency with 1,000 submissions in the database, and submissions
accepted per second.

The server runs for real (uvicorn in this process, no worker pool, so evaluation does not compete for the
CPU); requests go over loopback HTTP. The 1,000 submissions are inserted with their completed runs on all
nine boards (raw metrics random but fixed by a seed); episode rows are not needed by the board queries.

    python bench/bench_server.py [--database-url URL] [--submissions 1000] [--requests 200] [--accepts 100]
"""

from __future__ import annotations

import argparse
import random
import tempfile
import threading
import time
from pathlib import Path

import httpx
import uvicorn
from _common import machine, median, percentile

from robobpp.client.serve import BackgroundServer, create_policy_app
from robobpp.db.models import Participant, RunRow, Submission, utcnow
from robobpp.metrics import metrics_for
from robobpp.policies.dbl import DBL
from robobpp.server.app import create_app
from robobpp.server.bootstrap import bootstrap
from robobpp.server.config import Settings

ADMIN = "bench-admin-token-0123456789abcdef"
DATASETS = ("repetitive", "diverse", "longboard")
SETTINGS = ("math", "physics", "execution")


def seed_rows(runtime, n: int) -> None:  # type: ignore[no-untyped-def]
    rng = random.Random(0)
    now = utcnow()
    with runtime.session() as s:
        people = [Participant(name=f"team-{i:03d}") for i in range(100)]
        s.add_all(people)
        s.flush()
        for i in range(n):
            sub = Submission(participant_id=people[i % 100].id, name=f"policy-{i}", policy_url="https://example.org",
                             track="private", datasets=list(DATASETS), settings=list(SETTINGS),
                             status="completed", episodes_total=270, finished_at=now)  # fmt: skip
            s.add(sub)
            s.flush()
            for d in DATASETS:
                for st in SETTINGS:
                    metrics = {m.key: rng.random() for m in metrics_for(st)}
                    s.add(RunRow(submission_id=sub.id, dataset=d, setting=st, status="completed", episodes_total=30,
                                 metrics=metrics, extras={"episodes": 30}, completed_at=now))  # fmt: skip


def timed_gets(client: httpx.Client, path: str, n: int) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        r = client.get(path)
        out.append(time.perf_counter() - t0)
        r.raise_for_status()
    return out


def cold_gets(app, client: httpx.Client, path: str, n: int) -> list[float]:  # type: ignore[no-untyped-def]
    """As if a run had just completed: the version check misses and the board is recomputed."""
    from robobpp.server.services.boards import BoardCache

    out = []
    for _ in range(n):
        app.state.board_cache = BoardCache()
        out.extend(timed_gets(client, path, 1))
    return out


def accepts_per_second(client: httpx.Client, body: dict, n: int, threads: int) -> float:  # type: ignore[type-arg]
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--database-url", default="")
    parser.add_argument("--submissions", type=int, default=1000)
    parser.add_argument("--requests", type=int, default=200)
    parser.add_argument("--accepts", type=int, default=100)
    args = parser.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="robobpp-bench-"))
    url = args.database_url or f"sqlite:///{tmp / 'bench.sqlite3'}"
    settings = Settings(database_url=url, state_dir=tmp, admin_token=ADMIN, workers=0, evaluate_baselines=False,
                        settings=SETTINGS, groups=30, allow_private_policy_urls=True, quota_concurrent=10**6,
                        quota_submissions_per_day=10**6, spec_provider="robobpp.worker.specs:offline_spec")  # fmt: skip
    app = create_app(settings, start_workers=False)
    bootstrap(app.state.runtime)
    t0 = time.perf_counter()
    seed_rows(app.state.runtime, args.submissions)
    print(
        f"seeded {args.submissions} submissions x 9 boards in {time.perf_counter() - t0:.1f} s ({machine()})"
    )
    print(f"database: {app.state.runtime.engine.url.get_backend_name()}")

    server = uvicorn.Server(
        uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning", lifespan="off")
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    port = server.servers[0].sockets[0].getsockname()[1]
    base = f"http://127.0.0.1:{port}"
    with httpx.Client(base_url=base, timeout=60, headers={"Authorization": f"Bearer {ADMIN}"}) as client:
        timed_gets(client, "/api/v1/leaderboards/diverse/math", 5)  # warm-up
        rows = [
            ("GET /api/v1/leaderboards/diverse/math", timed_gets(client, "/api/v1/leaderboards/diverse/math",
                                                                   args.requests)),
            ("GET /api/v1/leaderboards/repetitive/execution",
             timed_gets(client, "/api/v1/leaderboards/repetitive/execution", args.requests)),
            ("same, cold (board recomputed: scores on read)", cold_gets(app, client, "/api/v1/leaderboards/diverse/math",
                                                                         max(20, args.requests // 4))),
            ("GET /api/v1/leaderboards (3 x 3 grid)", timed_gets(client, "/api/v1/leaderboards",
                                                                  max(10, args.requests // 10))),
        ]  # fmt: skip
        print("\n| request | n | p50 (ms) | p95 (ms) |\n|---|---|---|---|")
        for name, samples in rows:
            print(
                f"| {name} | {len(samples)} | {median(samples) * 1e3:.1f} | {percentile(samples, 95) * 1e3:.1f} |"
            )

        builtin = {"name": "bench", "policy_url": "builtin:dbl"}
        rate_builtin = accepts_per_second(client, builtin, args.accepts, 1)
        rate_builtin_4 = accepts_per_second(client, builtin, args.accepts, 4)
        with BackgroundServer(create_policy_app(DBL, "bench-secret-123")) as policy:
            remote = {"name": "bench", "policy_url": policy.url, "secret": "bench-secret-123"}
            rate_remote = accepts_per_second(client, remote, args.accepts, 1)
        print("\n| submission | clients | accepted per second |\n|---|---|---|")
        print(f"| builtin policy (no URL probe), 270 episode rows each | 1 | {rate_builtin:.1f} |")
        print(f"| builtin policy (no URL probe), 270 episode rows each | 4 | {rate_builtin_4:.1f} |")
        print(
            f"| policy URL (resolve, pin, signed GET /info), 270 episode rows each | 1 | {rate_remote:.1f} |"
        )
    server.should_exit = True
    thread.join(10)
    app.state.runtime.dispose()


if __name__ == "__main__":
    main()
