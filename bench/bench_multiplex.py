"""Episodes multiplexed per worker (robobpp/worker/multiplex.py): what a participant's think time costs the pool.

A real ``robobpp serve`` (2 local workers, SQLite, Math Pack) in a subprocess, participants' policies served by
the SDK in this process (one server per participant, each thinking ``--think`` seconds a box):

- ``latency``: a participant's 12 episodes thinking 1 s a box (public track, real data: ~80-box episodes) fill
  the workers; a second participant then submits 6 Math episodes of a fast DBL. Prints how long after its
  submission that one completed.
- ``throughput``: ``--submissions`` participants each submit ``--groups`` episodes thinking 1 s a box (offline
  12-box episodes); prints the episodes completed per hour over ``--window`` seconds, after the first claim.
  A participant's server (the SDK's) answers one request at a time: its episodes in flight share its second a
  box, so 20 participants decide at most 20 boxes a second however many episodes run; ``--max-running 1``
  gives each one episode at a time (its own policy), the comparison of N policies with N workers.
- ``memory``: the memory an episode in flight holds, per setting (``--settings``): ``--groups`` real episodes
  played to their end by DBL in this process and kept open (worlds, steps, observations), the growth of the
  resident set divided by their number (after one episode played and closed, for the imports and caches).
- ``builtin``: the built-in baselines (``--baselines``) evaluated at start, offline episodes; prints the wall
  time until all are done and the mean episode time.

``--episodes-per-worker`` sets ROBOBPP_EPISODES_PER_WORKER (1: one episode at a time); ``--code DIR`` runs the
server from another checkout (the code before the change: ``git archive <commit> | tar -x -C DIR``).
``--celery BROKER_URL`` runs the same scenario on the scaled deployment: ``robobpp serve`` dispatching to the
broker and ``robobpp worker --concurrency 2`` (2 worker processes, as the local pool's 2) running the episodes,
on a fresh PostgreSQL database made through ``--postgres`` and dropped after.

    python bench/bench_multiplex.py latency [--episodes-per-worker 16] [--code DIR]
    python bench/bench_multiplex.py throughput --submissions 20 [--episodes-per-worker 16] [--window 120]
    python bench/bench_multiplex.py builtin [--episodes-per-worker 16]
    python bench/bench_multiplex.py memory [--groups 8] [--settings math,physics]
    python bench/bench_multiplex.py latency --celery redis://127.0.0.1:6379/0 [--code DIR]
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
from sqlalchemy import create_engine, make_url, text

from robobpp.client.serve import BackgroundServer, create_policy_app
from robobpp.core import Action, Observation
from robobpp.policies.dbl import DBL

ADMIN = "bench-admin-token-0123456789abcdef"
SECRET = "policy-secret-123"
ROOT = Path(__file__).resolve().parent.parent


class Thinking(DBL):
    think_s = 1.0

    def act(self, obs: Observation) -> Action | None:
        time.sleep(self.think_s)
        return super().act(obs)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server:
    """``robobpp serve`` with its 2 local workers; with ``broker`` (``--celery``), ``robobpp serve`` dispatching to
    that broker and ``robobpp worker --concurrency 2`` running the episodes, on a fresh PostgreSQL database."""

    def __init__(
        self, state: Path, code: Path, broker: str | None = None, postgres: str = "", **env: str
    ) -> None:
        self.db = f"sqlite:///{state / 'bench.sqlite3'}"
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.broker, self.postgres, self.worker = broker, postgres, None
        self.tag = f"robobpp_bench_{uuid.uuid4().hex[:10]}"  # the database and the queue of this run
        environ = {k: v for k, v in os.environ.items() if not k.startswith("ROBOBPP_")}
        if broker:
            import psycopg

            with psycopg.connect(postgres, autocommit=True) as conn:
                conn.execute(f'CREATE DATABASE "{self.tag}"')
            self.db = (
                make_url(postgres)
                .set(drivername="postgresql+psycopg", database=self.tag)
                .render_as_string(hide_password=False)
            )
            environ.update(ROBOBPP_BROKER_URL=broker, ROBOBPP_CELERY_QUEUE=self.tag)
        environ.update(
            PYTHONPATH=str(code),
            ROBOBPP_STATE_DIR=str(state),
            ROBOBPP_DATABASE_URL=self.db,
            ROBOBPP_ADMIN_TOKEN=ADMIN,
            ROBOBPP_ALLOW_PRIVATE_POLICY_URLS="1",
            ROBOBPP_SETTINGS='["math"]',
            ROBOBPP_WORKERS="2",
            ROBOBPP_BOARD_REFRESH_S="0",
            ROBOBPP_QUOTA_SUBMISSIONS_PER_DAY="1000",
            **env,
        )
        command = [sys.executable, "-c", "from robobpp.cli import main; main()"]
        self.proc = subprocess.Popen(
            [*command, "serve", "--port", str(self.port)],
            env=environ,
            cwd=state,
            stdout=(state / "server.log").open("ab"),
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError((state / "server.log").read_text()[-3000:])
            try:
                if httpx.get(self.url + "/healthz", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.3)
        else:
            raise RuntimeError("the server did not start")
        if broker:  # after the server: it has migrated the database
            self.worker = subprocess.Popen(
                [*command, "worker", "--concurrency", "2"],
                env=environ,
                cwd=state,
                stdout=(state / "worker.log").open("ab"),
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
            wait(lambda: "ready" in (state / "worker.log").read_text(errors="replace"), 120)

    def groups(self) -> list[int]:
        """The process groups that run episodes: the server's, and the Celery workers' when there are some."""
        return [p.pid for p in (self.proc, self.worker) if p is not None]

    def client(self, token: str = ADMIN) -> httpx.Client:
        return httpx.Client(
            base_url=self.url + "/api/v1", headers={"Authorization": f"Bearer {token}"}, timeout=60
        )

    def participant(self, name: str) -> httpx.Client:
        r = self.client().post("/participants", json={"name": name})
        r.raise_for_status()
        return self.client(r.json()["token"])

    def rows(self, sql: str, **params: Any) -> list[Any]:
        engine = create_engine(self.db)
        try:
            with engine.connect() as conn:
                return list(conn.execute(text(sql), params).all())
        finally:
            engine.dispose()

    def stop(self) -> None:
        for proc in (self.worker, self.proc):
            if proc is None:
                continue
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
        if self.broker:
            import psycopg
            from kombu.connection import Connection

            with psycopg.connect(self.postgres, autocommit=True) as conn:
                conn.execute(f'DROP DATABASE IF EXISTS "{self.tag}" WITH (FORCE)')
            with Connection(self.broker) as conn:  # type: ignore[no-untyped-call]  # kombu: untyped __init__
                conn.default_channel.queue_delete(self.tag)
                conn.default_channel.exchange_delete(self.tag)


def group_cpu(pgids: list[int]) -> dict[int, float]:
    """CPU seconds of each process of some process groups (the server, its workers), by process id."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) in pgids:  # fields after the name: state, ppid, pgrp, ..., utime (11), stime (12)
            out[int(stat.parent.name)] = (int(fields[11]) + int(fields[12])) / tick
    return out


def when(value: Any) -> datetime:
    """A stored time (SQLite gives it back without its zone: UTC)."""
    moment = value if isinstance(value, datetime) else datetime.fromisoformat(str(value))
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def submit(client: httpx.Client, url: str, datasets: list[str], track: str) -> int:
    body = {"policy_url": url, "secret": SECRET, "datasets": datasets, "settings": ["math"], "track": track}
    r = client.post("/submissions", json=body)
    r.raise_for_status()
    return int(r.json()["id"])


def wait(predicate: Any, timeout_s: float, every_s: float = 0.2) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if value := predicate():
            return value
        time.sleep(every_s)
    raise TimeoutError


def latency(args: argparse.Namespace, state: Path, code: Path, extra: dict[str, str]) -> None:
    data = os.environ.get("ROBOBPP_DATA_DIR") or str(Path.home() / ".cache" / "robobpp")
    server = Server(
        state,
        code,
        args.celery,
        args.postgres,
        ROBOBPP_GROUPS="6",
        ROBOBPP_EVALUATE_BASELINES="0",
        ROBOBPP_DATA_DIR=data,
        **extra,
    )
    try:
        Thinking.think_s = args.think
        slow_policy = BackgroundServer(create_policy_app(Thinking, SECRET)).start()
        fast_policy = BackgroundServer(create_policy_app(DBL, SECRET)).start()
        many = submit(server.participant("slow"), slow_policy.url, ["diverse", "repetitive"], "public")
        running = (
            "SELECT count(*) FROM episodes WHERE submission_id = :s AND status = 'running' AND step >= 1"
        )
        wait(lambda: server.rows(running, s=many)[0][0] >= 2, 120)
        time.sleep(2)  # let the workers fill up as far as they will
        held = server.rows(running, s=many)[0][0]
        fast = server.participant("fast")
        sid = submit(fast, fast_policy.url, ["diverse"], "public")
        wait(lambda: fast.get(f"/submissions/{sid}").json()["status"] == "completed", 1200, 0.5)
        created, finished = server.rows(
            "SELECT created_at, finished_at FROM submissions WHERE id = :s", s=sid
        )[0]
        episode_s = server.rows(
            "SELECT avg(boxes_placed) FROM episodes WHERE submission_id = :s AND status = 'done'", s=sid
        )[0][0]
        print(
            f"slow participant's episodes running when the fast one was submitted: {held}; fast submission "
            f"(6 Math episodes of DBL, {episode_s:.0f} boxes placed on average) completed "
            f"{(when(finished) - when(created)).total_seconds():.1f} s after it was submitted"
        )
    finally:
        server.stop()


def throughput(args: argparse.Namespace, state: Path, code: Path, extra: dict[str, str]) -> None:
    server = Server(
        state,
        code,
        args.celery,
        args.postgres,
        ROBOBPP_GROUPS=str(args.groups),
        ROBOBPP_EVALUATE_BASELINES="0",
        ROBOBPP_SPEC_PROVIDER="robobpp.worker.specs:offline_spec",
        ROBOBPP_PARTICIPANT_MAX_RUNNING=str(args.max_running),
        **extra,
    )
    try:
        Thinking.think_s = args.think
        sids = []
        for i in range(args.submissions):
            policy = BackgroundServer(create_policy_app(Thinking, SECRET)).start()
            sids.append(submit(server.participant(f"p{i}"), policy.url, ["diverse"], "private"))
        wait(lambda: server.rows("SELECT min(started_at) FROM episodes")[0][0] is not None, 120)
        first = when(server.rows("SELECT min(started_at) FROM episodes")[0][0])
        samples, cpu0, mine0 = [], group_cpu(server.groups()), time.process_time()
        while time.time() < first.timestamp() + args.window:
            time.sleep(10)
            samples.append(server.rows("SELECT count(*) FROM episodes WHERE status = 'running'")[0][0])
        cpu = group_cpu(server.groups())
        used = sorted((cpu[p] - cpu0.get(p, 0.0)) / args.window for p in cpu)
        mine = (time.process_time() - mine0) / args.window
        cutoff = first.timestamp() + args.window
        done = [
            when(f)
            for (f,) in server.rows("SELECT finished_at FROM episodes WHERE status = 'done'")
            if when(f).timestamp() <= cutoff
        ]
        peak = server.rows("SELECT count(*) FROM episodes WHERE status = 'running'")[0][0]
        print(
            f"{args.submissions} submissions thinking {args.think:g} s a box: {len(done)} episodes done in "
            f"{args.window:.0f} s = {len(done) * 3600 / args.window:.0f} episodes/hour "
            f"({peak} running at the end of the window; every 10 s: {samples}); CPU (cores) of the server's "
            f"processes {', '.join(f'{u:.2f}' for u in used)}, of the policies' servers {mine:.2f}"
        )
    finally:
        server.stop()


def builtin(args: argparse.Namespace, state: Path, code: Path, extra: dict[str, str]) -> None:
    t0 = time.monotonic()
    server = Server(
        state,
        code,
        args.celery,
        args.postgres,
        ROBOBPP_GROUPS=str(args.groups),
        ROBOBPP_BASELINES=f"[{', '.join(repr(b).replace(chr(39), chr(34)) for b in args.baselines.split(','))}]",
        ROBOBPP_PUBLIC_BASELINES="0",
        ROBOBPP_SPEC_PROVIDER="robobpp.worker.specs:offline_spec",
        **extra,
    )
    try:
        left = "SELECT count(*) FROM episodes WHERE status NOT IN ('done', 'failed', 'cancelled')"
        wait(
            lambda: server.rows("SELECT count(*) FROM episodes")[0][0] > 0 and not server.rows(left)[0][0],
            1800,
        )
        wall = time.monotonic() - t0
        rows = server.rows("SELECT started_at, finished_at FROM episodes WHERE status = 'done'")
        first = min(when(s) for s, _ in rows)
        last = max(when(f) for _, f in rows)
        mean = sum((when(f) - when(s)).total_seconds() for s, f in rows) / len(rows)
        print(
            f"built-ins {args.baselines}: {len(rows)} episodes, first start to last finish "
            f"{(last - first).total_seconds():.1f} s (server start to all done {wall:.1f} s), "
            f"mean episode {mean:.2f} s"
        )
    finally:
        server.stop()


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def memory(args: argparse.Namespace, state: Path, code: Path, extra: dict[str, str]) -> None:
    os.environ.setdefault("ROBOBPP_DATA_DIR", str(Path.home() / ".cache" / "robobpp"))
    from robobpp.datasets import sampling
    from robobpp.episode import Episode, run_episode

    specs = sampling.episode_specs("diverse", "train", groups=args.groups + 1, seed=0)
    for setting in args.settings.split(","):
        run_episode(specs[-1], DBL(), setting)  # imports, caches, the first world's set-up
        before = rss_mb()
        kept = []
        for spec in specs[: args.groups]:
            episode, policy = Episode(spec, setting), DBL()
            policy.reset(episode.info)
            while not episode.done:
                episode.step(policy.act(episode.observe()), 0.0)
            kept.append(episode)
        grown = rss_mb() - before
        boxes = sum(e.index for e in kept) / len(kept)
        print(
            f"{setting}: {len(kept)} episodes in flight ({boxes:.0f} boxes each on average) hold "
            f"{grown:.0f} MB: {grown / len(kept):.1f} MB an episode (resident set {rss_mb():.0f} MB)"
        )
        for e in kept:
            e.setting.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", choices=("latency", "throughput", "builtin", "memory"))
    parser.add_argument("--episodes-per-worker", type=int, default=None)
    parser.add_argument("--code", type=Path, default=ROOT, help="checkout the server runs from")
    parser.add_argument("--think", type=float, default=1.0, help="seconds a box the slow policies think")
    parser.add_argument("--submissions", type=int, default=20)
    parser.add_argument("--groups", type=int, default=10)
    parser.add_argument("--window", type=float, default=120.0)
    parser.add_argument(
        "--max-running", type=int, default=4, help="ROBOBPP_PARTICIPANT_MAX_RUNNING (throughput)"
    )
    parser.add_argument("--baselines", default="dbl,lsah,hm")
    parser.add_argument(
        "--celery",
        metavar="BROKER_URL",
        default=None,
        help="run the episodes on `robobpp worker --concurrency 2` through this broker (redis://… or amqp://…), "
        "the server dispatching; on a fresh database of --postgres",
    )
    parser.add_argument(
        "--postgres",
        default="postgresql://postgres@127.0.0.1:5432/postgres",
        help="a PostgreSQL URL allowed to create and drop a database (--celery)",
    )
    parser.add_argument("--settings", default="math,physics")
    args = parser.parse_args()
    extra = {}
    if args.episodes_per_worker is not None:
        extra["ROBOBPP_EPISODES_PER_WORKER"] = str(args.episodes_per_worker)
    with tempfile.TemporaryDirectory() as tmp:
        {"latency": latency, "throughput": throughput, "builtin": builtin, "memory": memory}[args.scenario](
            args, Path(tmp), args.code.resolve(), extra
        )


if __name__ == "__main__":
    main()
