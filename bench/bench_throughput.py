"""Celery executor throughput: episodes per minute with 1 and 2 ``robobpp worker`` processes, Math and
Physics Pack, DBL on real Repetitive train groups, real Redis + PostgreSQL (a fresh database and queue
per measurement, dropped afterwards).

    python bench/bench_throughput.py [--math-episodes 60] [--physics-episodes 8] [--broker redis://...]

Each measurement: start N workers (``--concurrency 1`` each), wait until all answer a ping, then let the
dispatcher enqueue one submission and time until its last episode is recorded. Also reported: the mean
wall time of one episode inside a worker (``finished_at - started_at``), from which the capacity plan in
docs/deploy.md derives episodes per core-hour.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

from _common import machine

ROOT = Path(__file__).resolve().parents[1]
PG_ADMIN = "postgresql://postgres@127.0.0.1:5432/test"


def _measure(setting: str, workers: int, episodes: int, broker: str) -> dict[str, float]:
    import psycopg
    from sqlalchemy import select

    from robobpp.db import work
    from robobpp.db.migrate import upgrade
    from robobpp.db.models import EpisodeRow, Participant, Submission
    from robobpp.db.session import make_engine, make_session_factory
    from robobpp.vocabulary import ACTIVE_SUBMISSION
    from robobpp.worker.celery_app import make_celery
    from robobpp.worker.celery_executor import CeleryExecutor, count_workers
    from robobpp.worker.options import WorkerOptions

    name = f"robobpp_bench_{uuid.uuid4().hex[:8]}"
    queue = f"robobpp-bench-{uuid.uuid4().hex[:8]}"
    with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    url = f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}"
    engine = make_engine(url)
    procs: list[subprocess.Popen[bytes]] = []
    executor = None
    log = tempfile.TemporaryFile()  # noqa: SIM115 - the workers write to it until the finally block
    try:
        upgrade(url)
        factory = make_session_factory(engine)
        with factory() as s, s.begin():
            who = Participant(name="bench")
            s.add(who)
            s.flush()
            sub = work.create_submission(
                s,
                who,
                name="bench",
                policy_url="builtin:dbl",
                datasets=["repetitive"],
                settings=[setting],
                groups=episodes,
                track="public",
            ).id
        env = {k: v for k, v in os.environ.items() if not k.startswith("ROBOBPP_")}
        env.update(
            ROBOBPP_DATABASE_URL=url,
            ROBOBPP_BROKER_URL=broker,
            ROBOBPP_CELERY_QUEUE=queue,
            ROBOBPP_GROUPS=str(episodes),
            ROBOBPP_ENV="dev",
        )
        for i in range(workers):
            cmd = [
                sys.executable,
                "-c",
                "from robobpp.cli import main; main()",
                "worker",
                "--concurrency",
                "1",
                "--loglevel",
                "warning",
                "--hostname",
                f"bench{i}-{queue}@local",
            ]
            procs.append(
                subprocess.Popen(
                    cmd, env=env, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
                )
            )
        app = make_celery(broker, WorkerOptions(database_url=url, groups=episodes), queue=queue)
        deadline = time.monotonic() + 120
        while count_workers(app, timeout=0.5) < workers:
            if time.monotonic() > deadline:
                log.seek(0)
                raise RuntimeError("workers did not start:\n" + log.read().decode(errors="replace")[-3000:])
        t0 = time.monotonic()
        executor = CeleryExecutor(app)
        executor.start()
        while True:
            with factory() as s:
                status = s.execute(select(Submission.status).where(Submission.id == sub)).scalar_one()
            if status not in ACTIVE_SUBMISSION:
                break
            time.sleep(0.1)
        elapsed = time.monotonic() - t0
        with factory() as s:
            rows = s.execute(select(EpisodeRow).where(EpisodeRow.submission_id == sub)).scalars().all()
            durations = []
            for r in rows:
                if r.status == "done":
                    assert r.finished_at is not None and r.started_at is not None  # set when it finished
                    durations.append((r.finished_at - r.started_at).total_seconds())
        if status != "completed" or len(durations) != episodes:
            raise RuntimeError(f"submission ended {status} with {len(durations)}/{episodes} episodes done")
        return {
            "elapsed_s": elapsed,
            "per_min": episodes / elapsed * 60,
            "episode_s": sum(durations) / len(durations),
        }
    finally:
        if executor is not None:
            executor.stop()
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        engine.dispose()
        log.close()
        with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        from kombu.connection import Connection

        with Connection(broker) as conn:  # type: ignore[no-untyped-call]  # kombu: untyped __init__
            conn.default_channel.queue_delete(queue)
            conn.default_channel.exchange_delete(queue)
            if broker.startswith("redis"):
                conn.default_channel.client.delete(
                    f"_kombu.binding.{queue}", f"_kombu.binding_permanent.{queue}"
                )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--math-episodes", type=int, default=60)
    parser.add_argument("--physics-episodes", type=int, default=8)
    parser.add_argument("--broker", default="redis://127.0.0.1:6379/0")
    args = parser.parse_args()
    load = os.getloadavg()
    print(f"machine: {machine()}; load average at start {load[0]:.2f} (cores shared with other jobs)")
    print(
        "| setting | episodes | workers | wall (s) | episodes/min | mean episode in worker (s) | ratio 2:1 |"
    )
    print("|---|---|---|---|---|---|---|")
    for setting, episodes in (("math", args.math_episodes), ("physics", args.physics_episodes)):
        if episodes <= 0:
            continue
        one = _measure(setting, 1, episodes, args.broker)
        two = _measure(setting, 2, episodes, args.broker)
        for n, r in ((1, one), (2, two)):
            ratio = f"{two['per_min'] / one['per_min']:.2f}" if n == 2 else ""
            print(
                f"| {setting} | {episodes} | {n} | {r['elapsed_s']:.1f} | {r['per_min']:.1f} | "
                f"{r['episode_s']:.2f} | {ratio} |"
            )
    print(f"load average at end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
