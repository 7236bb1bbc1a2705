"""Protocol overhead per step on loopback: remote DBL minus in-process DBL, same episodes, same steps.

The policy server runs in its own process (``robobpp policy serve dbl``), as a participant's would, so
client and server do not share a GIL. Each step's overhead is the caller-measured decision time of the
remote step minus that of the same step in-process (the states are identical: DBL is deterministic).

    python bench/bench_protocol.py [--episodes 10] [--boxes 80] [--secret s] [--json out.json]
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
        return sock.getsockname()[1]


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
    parser.add_argument("--json", dest="json_out", default=None)
    args = parser.parse_args()

    port = free_port()
    server = start_server(port, args.secret)
    try:
        remote = RemotePolicy(f"http://127.0.0.1:{port}", args.secret)
        episodes = specs(args.episodes, args.boxes)
        run_episode(episodes[0], remote, "math")  # warm-up: connection, imports, caches
        run_episode(episodes[0], DBL(), "math")
        overhead: list[float] = []
        remote_t: list[float] = []
        local_t: list[float] = []
        compute: list[float] = []
        cpu_remote = cpu_local = 0.0
        server_before = server_cpu_s(server.pid)
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
        server_after = server_cpu_s(server.pid)
    finally:
        server.terminate()
        server.wait(timeout=10)
    steps = len(overhead)
    # CPU spent on the protocol per step, both processes, excluding the policy's own compute: a figure
    # that a busy machine's scheduling delays do not inflate (the wall-clock ones above they do).
    cpu_overhead = None
    if server_before is not None and server_after is not None:
        spent = (cpu_remote - cpu_local) + (server_after - server_before) - sum(compute)
        cpu_overhead = spent / steps * 1000.0
    figures = {
        "steps": steps,
        "signed": bool(args.secret),
        "overhead_p50_ms": pct(overhead, 50),
        "overhead_p95_ms": pct(overhead, 95),
        "remote_p50_ms": pct(remote_t, 50),
        "remote_p95_ms": pct(remote_t, 95),
        "in_process_p50_ms": pct(local_t, 50),
        "in_process_p95_ms": pct(local_t, 95),
        "server_compute_p50_ms": pct(compute, 50) if compute else None,
        "cpu_overhead_mean_ms": cpu_overhead,
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
