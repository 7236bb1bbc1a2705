"""SQLite read latency under 20 concurrent readers while an evaluation writes (issue 20, point 4).

A real ``robobpp serve`` process on SQLite with its local worker pool evaluates built-in baselines on
synthetic offline episodes (short episodes: the workers claim, renew and complete often, so the write lock
is busy); meanwhile 20 reader threads in this process run the reads of the API's GET routes (a submission's
progress, its episode list, the leaderboard rows, the status counts) through the same engine set-up the
API uses (``make_engine(url, read_only=True)``: deferred ``BEGIN``, ``query_only``, WAL, busy timeout).
``--begin immediate`` reads through the writers' engine instead (``BEGIN IMMEDIATE``, what every read took
before), for comparison. Every read transaction's wall time is recorded; the table gives p50, p99, max.

    python bench/bench_sqlite_reads.py [--seconds 60] [--readers 20] [--workers 2] [--begin deferred|immediate]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
from _common import machine, median, percentile

ADMIN = "bench-admin-token-0123456789abcdef"
BASELINES = ("dbl", "hm", "lsah", "onlinebph", "br")


def start_server(state: Path, workers: int) -> tuple[subprocess.Popen[bytes], str]:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROBOBPP_")}
    env.update(
        {
            "ROBOBPP_STATE_DIR": str(state),
            "ROBOBPP_ADMIN_TOKEN": ADMIN,
            "ROBOBPP_WORKERS": str(workers),
            "ROBOBPP_SPEC_PROVIDER": "robobpp.worker.specs:offline_spec",
            "ROBOBPP_SETTINGS": '["math"]',
            "ROBOBPP_GROUPS": "30",
            "ROBOBPP_EVALUATE_BASELINES": "0",
            "ROBOBPP_POLL_INTERVAL_S": "0.2",
        }
    )
    log = (state / "server.log").open("ab")
    proc = subprocess.Popen(
        [sys.executable, "-c", "from robobpp.cli import main; main()", "serve", "--port", str(port)],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=state,
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            if httpx.get(url + "/healthz", timeout=2).status_code == 200:
                return proc, url
        except httpx.HTTPError:
            pass
        time.sleep(0.3)
    proc.kill()
    raise SystemExit("server did not start: " + (state / "server.log").read_text()[-2000:])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60)
    ap.add_argument("--readers", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--begin", choices=("deferred", "immediate"), default="deferred")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        proc, url = start_server(Path(tmp), args.workers)
        try:
            api = httpx.Client(
                base_url=url + "/api/v1", headers={"Authorization": f"Bearer {ADMIN}"}, timeout=120
            )
            ids = []
            for name in BASELINES:
                r = api.post("/submissions", json={"name": name, "policy_url": f"builtin:{name}"})
                r.raise_for_status()
                ids.append(r.json()["id"])
            from sqlalchemy.orm import Session

            from robobpp.boards.engine import leaderboard
            from robobpp.db import queries
            from robobpp.db.session import make_engine, make_session_factory

            engine = make_engine(
                f"sqlite:///{Path(tmp) / 'robobpp.sqlite3'}", read_only=args.begin == "deferred"
            )
            factory = make_session_factory(engine)
            latencies: list[float] = []
            lock = threading.Lock()
            stop = time.monotonic() + args.seconds

            def read(session: Session, k: int) -> None:
                sub_id = ids[k % len(ids)]
                if k % 4 == 0:
                    queries.episode_rows(session, sub_id)
                elif k % 4 == 1:
                    leaderboard(session, "diverse", "math")
                elif k % 4 == 2:
                    queries.episode_status_counts(session)
                else:
                    queries.submission_status_counts(session)

            def reader(k: int) -> None:
                i = k
                while time.monotonic() < stop:
                    t0 = time.perf_counter()
                    with factory() as session, session.begin():
                        read(session, i)
                    with lock:
                        latencies.append(time.perf_counter() - t0)
                    i += 1

            threads = [threading.Thread(target=reader, args=(k,)) for k in range(args.readers)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            engine.dispose()
            done = sum(api.get(f"/submissions/{i}").json()["progress"]["episodes_done"] for i in ids)
        finally:
            proc.terminate()
            proc.wait(30)
    ms = [x * 1000 for x in latencies]
    print(f"machine: {machine()}; load {os.getloadavg()[0]:.1f}")
    print(
        f"{len(ms)} reads by {args.readers} readers in {args.seconds:g} s while {args.workers} workers "
        f"completed {done} episodes"
    )
    print("| reads begin | readers | reads | episodes written | p50 (ms) | p99 (ms) | max (ms) |")
    print(
        f"| {args.begin} | {args.readers} | {len(ms)} | {done} | {median(ms):.1f} | {percentile(ms, 99):.1f} | {max(ms):.1f} |"
    )


if __name__ == "__main__":
    main()
