"""The pull relay's bus alone: what one step costs through Redis or RabbitMQ (two API processes) vs in-process.

A pull step is one frame from the worker's side to the client's side and one back. Here two endpoints of the
relay bus (robobpp/server/relay_bus.py) exchange such frames, with nothing else around them: on one
``LocalBus`` (one API process), and on two ``RedisBus`` es with different node ids (what two API processes
are: each frame is a ``PUBLISH`` to the other's channel and a delivery by its listener), and on two
``AmqpBus`` es (a publish to the other's exclusive queue, consumed by its thread). Both buses run in
this one process and event loop, so the figures are the bus's own added latency and CPU per step, not a
scheduling race between processes; the broker's own CPU is not counted. The GIL switch interval is the API
process's (``ROBOBPP_SWITCH_INTERVAL_S``), since the AMQP bus hands messages between threads.

    python bench/bench_relay_bus.py [--exchanges 2000] [--size 3000] [--rounds 2] [--redis redis://127.0.0.1:6379/0]
        [--amqp amqp://guest:guest@127.0.0.1:5672//]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import time
import uuid

import numpy as np

from robobpp.server.config import Settings
from robobpp.server.relay_amqp import AmqpBus
from robobpp.server.relay_bus import FRAME, LocalBus, RedisBus


async def exchange(buses: tuple[LocalBus, LocalBus], exchanges: int, size: int) -> tuple[list[float], float]:
    """Per-exchange wall times (s) and CPU seconds per exchange, worker side ↔ client side."""
    for bus in set(buses):
        await bus.start()
    worker, client = buses[0].endpoint(), buses[1].endpoint()
    payload = b"0" * size

    async def echo() -> None:
        while True:
            message = await client.inbox.get()
            await client.send(message.sender, FRAME, message.payload[:64])

    echoing = asyncio.create_task(echo())
    times: list[float] = []
    try:
        for _ in range(50):  # warm-up: connections in the pool, caches
            await worker.send(client.address, FRAME, payload)
            await worker.inbox.get()
        cpu = time.process_time()
        for _ in range(exchanges):
            t0 = time.perf_counter()
            await worker.send(client.address, FRAME, payload)
            await worker.inbox.get()
            times.append(time.perf_counter() - t0)
        cpu = (time.process_time() - cpu) / exchanges
    finally:
        echoing.cancel()
        for bus in set(buses):
            await bus.close()
    return times, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--exchanges", type=int, default=2000)
    parser.add_argument(
        "--size", type=int, default=3000, help="bytes of the worker's frame (an /act is ~3 kB)"
    )
    parser.add_argument("--rounds", type=int, default=2, help="interleaved rounds of each bus")
    parser.add_argument(
        "--redis", default=os.environ.get("ROBOBPP_PULL_BROKER_URL") or "redis://127.0.0.1:6379/0"
    )
    parser.add_argument("--amqp", default="amqp://guest:guest@127.0.0.1:5672//")
    parser.add_argument("--json", dest="json_out", default=None)
    args = parser.parse_args()
    # as the API process runs (ROBOBPP_SWITCH_INTERVAL_S): the AMQP bus's threads hand messages to the loop
    sys.setswitchinterval(Settings().switch_interval_s)

    results: dict[str, dict[str, list[float]]] = {}
    for _ in range(args.rounds):
        for kind in ("in-process", "redis", "rabbitmq"):
            deployment = f"bench-{uuid.uuid4().hex[:8]}"
            if kind == "in-process":
                local = LocalBus()
                buses: tuple[LocalBus, LocalBus] = (local, local)
            elif kind == "redis":
                buses = (RedisBus(args.redis, deployment), RedisBus(args.redis, deployment))
            else:
                buses = (AmqpBus(args.amqp, deployment), AmqpBus(args.amqp, deployment))
            times, cpu = asyncio.run(exchange(buses, args.exchanges, args.size))
            entry = results.setdefault(kind, {"p50_ms": [], "p95_ms": [], "cpu_us": []})
            entry["p50_ms"].append(float(np.percentile(times, 50)) * 1000)
            entry["p95_ms"].append(float(np.percentile(times, 95)) * 1000)
            entry["cpu_us"].append(cpu * 1e6)
    for kind, entry in results.items():
        print(
            f"{kind:10s} p50 {' / '.join(f'{v:.3f}' for v in entry['p50_ms'])} ms   "
            f"p95 {' / '.join(f'{v:.3f}' for v in entry['p95_ms'])} ms   "
            f"CPU {' / '.join(f'{v:.0f}' for v in entry['cpu_us'])} µs per step"
        )
    base = np.median(results["in-process"]["p50_ms"])
    added = {kind: float(np.median(results[kind]["p50_ms"]) - base) for kind in ("redis", "rabbitmq")}
    for kind, ms in added.items():
        print(f"added by {kind} per step (p50, median of rounds): {ms:.3f} ms")
    if args.json_out:
        with open(args.json_out, "w", encoding="utf-8") as fh:
            json.dump(
                {
                    **results,
                    "added_p50_ms": added,
                    "cpu_count": os.cpu_count(),
                    "python": sys.version.split()[0],
                },
                fh,
                indent=2,
            )


if __name__ == "__main__":
    main()
