"""Protocol overhead per step on loopback: remote DBL minus in-process DBL, same episodes, same steps.

The policy server runs in its own process (``robobpp policy serve dbl``), as a participant's would, so
client and server do not share a GIL. Each step's overhead is the caller-measured decision time of the
remote step minus that of the same step in-process (the states are identical: DBL is deterministic).

``--mode pull`` measures pull mode instead: a real ``robobpp serve`` (SQLite, no workers) relays between
this process, which plays the worker (it holds the lease of a pull episode), and ``robobpp connect dbl``
in its own process. ``--probe`` adds the echo probes of the network estimate and reports their figures.
``--relay redis`` runs pull mode across two API processes on one database whose relays meet through Redis
(``ROBOBPP_PULL_BROKER_URL``, default ``redis://127.0.0.1:6379/0``): the client connects to one, the worker
(this process) to the other, so every frame crosses the broker both ways.

    python bench/bench_protocol.py [--mode push|pull] [--relay in-process|redis] [--probe] [--episodes 10]
        [--boxes 80] [--secret s]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time

import numpy as np

from robobpp.client.remote import RemotePolicy
from robobpp.core import Box, ContainerSpec, EpisodeSpec
from robobpp.episode import run_episode
from robobpp.policies.dbl import DBL


def specs(episodes: int, boxes: int) -> list[EpisodeSpec]:
    """Deterministic Diverse-sized episodes (no data download needed)."""
    out = []
    for group in range(episodes):
        rng = np.random.default_rng(1000 + group)
        dims = rng.integers(10, 50, size=(boxes, 3))
        items = tuple(Box(float(a), float(b), float(c), 2.0) for a, b, c in dims)
        out.append(EpisodeSpec("bench", "train", group, items, ContainerSpec(120, 100, 170), 4.0, group))
    return out


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def start_server(port: int, secret: str | None) -> subprocess.Popen[bytes]:
    code = "import sys; from robobpp.cli import main; sys.argv = ['robobpp', *sys.argv[1:]]; main()"
    args = [sys.executable, "-c", code, "policy", "serve", "dbl", "--port", str(port)]
    env = dict(os.environ)
    if secret:
        env["ROBOBPP_POLICY_SECRET"] = secret
    proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return proc
        except OSError:
            time.sleep(0.1)
    proc.kill()
    raise RuntimeError("policy server did not start")


class PullRig:
    """A relay server, a participant's ``robobpp connect dbl`` and a claimed pull episode to drive through."""

    ADMIN = "bench-admin-token-0123456789abcdef"

    def __init__(self, state_dir: str, secret: str | None, redis_url: str = "") -> None:
        import httpx

        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.worker_url = self.url
        db = f"sqlite:///{state_dir}/bench.sqlite3"
        env = {k: v for k, v in os.environ.items() if not k.startswith("ROBOBPP_")}
        env.update(
            {
                "ROBOBPP_STATE_DIR": state_dir,
                "ROBOBPP_DATABASE_URL": db,
                "ROBOBPP_ADMIN_TOKEN": self.ADMIN,
                "ROBOBPP_WORKERS": "0",
                "ROBOBPP_EVALUATE_BASELINES": "0",
                "ROBOBPP_GROUPS": "1",
                "ROBOBPP_SETTINGS": '["math"]',
                "ROBOBPP_SPEC_PROVIDER": "robobpp.worker.specs:offline_spec",
                "ROBOBPP_LEASE_S": "3600",
                "ROBOBPP_PULL_BROKER_URL": redis_url,
            }
        )
        code = "import sys; from robobpp.cli import main; sys.argv = ['robobpp', *sys.argv[1:]]; main()"
        self.procs = [self._serve(code, self.port, env)]
        wait_healthy(self.url)
        api = httpx.Client(base_url=self.url + "/api/v1", headers={"Authorization": f"Bearer {self.ADMIN}"})
        token = api.post("/participants", json={"name": "bench"}).json()["token"]
        body = {"name": "bench", "mode": "pull", "datasets": ["diverse"], "settings": ["math"]}
        if secret:
            body["secret"] = secret
        mine = httpx.Client(base_url=self.url + "/api/v1", headers={"Authorization": f"Bearer {token}"})
        self.submission = mine.post("/submissions", json=body).json()["id"]
        client_env = dict(os.environ, ROBOBPP_TOKEN=token, ROBOBPP_SERVER=self.url)
        if secret:
            client_env["ROBOBPP_POLICY_SECRET"] = secret
        self.procs.append(
            subprocess.Popen(
                [sys.executable, "-c", code, "connect", "dbl", "--submission", str(self.submission)],
                env=client_env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
        from robobpp.db import work
        from robobpp.db.session import make_engine, make_session_factory

        factory = make_session_factory(make_engine(db))
        with factory() as session, session.begin():
            claim = work.claim_episode(session, "bench:worker", lease_s=3600, max_attempts=3)
        assert claim is not None and claim.mode == "pull"
        self.claim = claim
        if redis_url:  # a second API process on the same database: the worker's side of the relay
            port = free_port()
            self.worker_url = f"http://127.0.0.1:{port}"
            self.procs.append(self._serve(code, port, env))
            wait_healthy(self.worker_url)

    @staticmethod
    def _serve(code: str, port: int, env: dict[str, str]) -> subprocess.Popen[bytes]:
        return subprocess.Popen(
            [sys.executable, "-c", code, "serve", "--port", str(port)],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )

    def policy(self, secret: str | None, probe: bool) -> RemotePolicy:
        from robobpp.worker.pull import PullTransport

        transport = PullTransport(self.worker_url, self.claim.episode_id, self.claim.token, wait_s=30)
        policy = RemotePolicy(self.url, secret, transport=transport, probe_network=probe)
        transport.headers_for = policy.request_headers
        return policy

    def stop(self) -> None:
        for proc in reversed(self.procs):
            proc.terminate()
            proc.wait(timeout=20)


def wait_healthy(url: str, timeout_s: float = 60.0) -> None:
    import httpx

    deadline = time.monotonic() + timeout_s
    while True:
        try:
            if httpx.get(url + "/healthz", timeout=1).status_code == 200:
                return
        except httpx.HTTPError:
            if time.monotonic() > deadline:
                raise RuntimeError(f"the relay server at {url} did not start") from None
        time.sleep(0.3)


def server_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of the server process (Linux /proc), None elsewhere."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) * 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--boxes", type=int, default=80)
    parser.add_argument("--secret", default=None, help="sign every request (HMAC-SHA256)")
    parser.add_argument("--mode", choices=("push", "pull"), default="push")
    parser.add_argument("--probe", action="store_true", help="echo probes before each act (network estimate)")
    parser.add_argument(
        "--relay",
        choices=("in-process", "redis"),
        default="in-process",
        help="pull mode: one API process, or two through Redis",
    )
    parser.add_argument(
        "--redis", default=os.environ.get("ROBOBPP_PULL_BROKER_URL") or "redis://127.0.0.1:6379/0"
    )
    parser.add_argument("--json", dest="json_out", default=None)
    args = parser.parse_args()

    import tempfile

    tmp = tempfile.TemporaryDirectory()
    rig = None
    if args.mode == "pull":
        rig = PullRig(tmp.name, args.secret, args.redis if args.relay == "redis" else "")
        server = rig.procs[1]  # the participant's process: the policy's side, as in push mode
    else:
        port = free_port()
        server = start_server(port, args.secret)
    probes: list[float] = []
    round_trips: list[float] = []
    try:
        if rig is not None:
            remote = rig.policy(args.secret, args.probe)
        else:
            remote = RemotePolicy(f"http://127.0.0.1:{port}", args.secret, probe_network=args.probe)
        episodes = specs(args.episodes, args.boxes)
        run_episode(episodes[0], remote, "math")  # warm-up: connection, imports, caches
        run_episode(episodes[0], DBL(), "math")
        overhead: list[float] = []
        remote_t: list[float] = []
        local_t: list[float] = []
        compute: list[float] = []
        cpu_remote = cpu_local = 0.0
        server_before = server_cpu_s(server.pid)
        relays = [p.pid for i, p in enumerate(rig.procs) if i != 1] if rig is not None else []
        relay_before = [server_cpu_s(pid) for pid in relays]
        for spec in episodes:
            c0 = time.process_time()
            r = run_episode(spec, remote, "math")
            c1 = time.process_time()
            loc = run_episode(spec, DBL(), "math")
            cpu_remote += c1 - c0
            cpu_local += time.process_time() - c1
            assert r.final == loc.final, "remote and in-process DBL diverged"
            for rs, ls in zip(r.steps, loc.steps, strict=True):
                overhead.append(rs.decision_time - ls.decision_time)
                remote_t.append(rs.decision_time)
                local_t.append(ls.decision_time)
                if rs.compute_time is not None:
                    compute.append(rs.compute_time)
                if rs.round_trip is not None:
                    round_trips.append(rs.round_trip)
                if rs.network_estimate is not None:
                    probes.append(rs.network_estimate)
        server_after = server_cpu_s(server.pid)
        relay_after = [server_cpu_s(pid) for pid in relays]
    finally:
        if rig is not None:
            rig.stop()
        else:
            server.terminate()
            server.wait(timeout=10)
        tmp.cleanup()
    steps = len(overhead)
    # CPU spent on the protocol per step, both processes, excluding the policy's own compute: a figure
    # that a busy machine's scheduling delays do not inflate (the wall-clock ones above they do).
    cpu_overhead = None
    if server_before is not None and server_after is not None:
        spent = (cpu_remote - cpu_local) + (server_after - server_before) - sum(compute)
        cpu_overhead = spent / steps * 1000.0
    # pull mode: CPU of the API process(es) relaying, per step (both of them with --relay redis)
    relay_cpu = None
    if relays:
        spent_s = [
            a - b for a, b in zip(relay_after, relay_before, strict=True) if a is not None and b is not None
        ]
        if len(spent_s) == len(relays):  # every relay's CPU time read, before and after
            relay_cpu = sum(spent_s) / steps * 1000.0
    figures = {
        "mode": args.mode,
        "relay": args.relay if args.mode == "pull" else None,
        "probe": args.probe,
        "steps": steps,
        "signed": bool(args.secret),
        "overhead_p50_ms": pct(overhead, 50),
        "overhead_p95_ms": pct(overhead, 95),
        "remote_p50_ms": pct(remote_t, 50),
        "remote_p95_ms": pct(remote_t, 95),
        "in_process_p50_ms": pct(local_t, 50),
        "in_process_p95_ms": pct(local_t, 95),
        "server_compute_p50_ms": pct(compute, 50) if compute else None,
        "round_trip_p50_ms": pct(round_trips, 50) if round_trips else None,
        "network_estimate_p50_ms": pct(probes, 50) if probes else None,
        "cpu_overhead_mean_ms": cpu_overhead,
        "relay_cpu_per_step_ms": relay_cpu,
        "cpu_count": os.cpu_count(),
        "python": sys.version.split()[0],
    }
    for key, value in figures.items():
        print(f"{key:24s} {value:.3f}" if isinstance(value, float) else f"{key:24s} {value}")
    print(f"target overhead p50 <= 2 ms: {'met' if figures['overhead_p50_ms'] <= 2.0 else 'NOT met'}")
    if args.json_out:
        with open(args.json_out, "w", encoding="utf-8") as fh:
            json.dump(figures, fh, indent=2)


if __name__ == "__main__":
    main()
