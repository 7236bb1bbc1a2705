"""A lean HTTP/1.1 load generator for the server benchmark: closed-loop readers over keep-alive
connections, in a process of its own so its CPU is measured apart from the server's.

asyncio streams and a minimal response parser (Content-Length or chunked bodies) instead of an HTTP
client library: on a small machine the load generator shares the cores with the server, so what each of
its requests costs is CPU taken from the server.
"""

from __future__ import annotations

import asyncio
import resource
import time
from collections.abc import Sequence
from typing import TypedDict
from urllib.parse import urlsplit

Route = tuple[str, str, dict[str, str]]  # (label, path, extra headers)


class LoadResult(TypedDict):
    latencies: dict[str, list[float]]  # per route label, s
    errors: list[str]  # the first five
    error_count: int
    elapsed: float  # the measured phase's wall time, s
    cpu: float  # this process's CPU time over it, s


async def _read_response(reader: asyncio.StreamReader) -> tuple[int, int]:
    head = await reader.readuntil(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split(" ", 2)[1])
    length, chunked = None, False
    for line in lines[1:]:
        name, _, value = line.partition(":")
        name = name.strip().lower()
        if name == "content-length":
            length = int(value)
        elif name == "transfer-encoding" and "chunked" in value.lower():
            chunked = True
    if length is not None:
        await reader.readexactly(length)
        return status, length
    if not chunked:
        raise RuntimeError("response without a length")
    size = 0
    while True:
        n = int((await reader.readuntil(b"\r\n")).split(b";")[0], 16)
        await reader.readexactly(n + 2)
        size += n
        if n == 0:
            return status, size


async def _run(
    base: str,
    routes: Sequence[Route],
    readers: int,
    samples: int,
    warm: int,
) -> LoadResult:
    split = urlsplit(base)
    host, port = split.hostname or "127.0.0.1", split.port or 80
    out: dict[str, list[float]] = {label: [] for label, _, _ in routes}
    errors: list[str] = []
    total = samples * len(routes)
    issued = 0

    def request(path: str, headers: dict[str, str]) -> bytes:
        extra = "".join(f"{k}: {v}\r\n" for k, v in headers.items())
        return f"GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\n{extra}\r\n".encode("latin-1")

    conns = [await asyncio.open_connection(host, port) for _ in range(readers)]
    orders = [list(routes[k % len(routes) :]) + list(routes[: k % len(routes)]) for k in range(readers)]

    async def warm_up(k: int) -> None:  # each connection asks each route once, unmeasured
        r, w = conns[k]
        for _ in range(warm):
            for _label, path, headers in orders[k]:
                w.write(request(path, headers))
                await _read_response(r)

    async def reader(k: int) -> None:
        nonlocal issued
        r, w = conns[k]
        i = 0
        while issued < total:
            issued += 1
            label, path, headers = orders[k][i % len(orders[k])]
            i += 1
            t0 = time.perf_counter()
            w.write(request(path, headers))
            status, _ = await _read_response(r)
            out[label].append(time.perf_counter() - t0)
            if status != 200:
                errors.append(f"{path}: HTTP {status}")

    await asyncio.gather(*(warm_up(k) for k in range(readers)))
    cpu0, t0 = _cpu(), time.perf_counter()
    await asyncio.gather(*(reader(k) for k in range(readers)))
    cpu, elapsed = _cpu() - cpu0, time.perf_counter() - t0
    for _r, w in conns:
        w.close()
    return {
        "latencies": out,
        "errors": errors[:5],
        "error_count": len(errors),
        "elapsed": elapsed,
        "cpu": cpu,
    }


def _cpu() -> float:
    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime


def read_concurrently(
    base: str,
    routes: Sequence[Route],
    readers: int,
    samples: int,
    warm: int = 1,
) -> LoadResult:
    """Run in a child process: per-route latencies (s), errors, the measured phase's wall time and this
    process's CPU time over it."""
    return asyncio.run(_run(base, routes, readers, samples, warm))
