"""Pull mode's transport, chosen by measurement: WebSocket against HTTP long-poll, server to client and back.

In pull mode the server must hand a request to a client that connected out to it and get the answer back.
Both candidates keep one connection open; they differ in framing: a WebSocket frame each way, or a pending
``POST /poll`` whose *response* carries the request and whose successor's *body* carries the answer (one
HTTP exchange per step). The server side (uvicorn + FastAPI, as in ``robobpp serve``) times each exchange
from handing the request over to holding the answer; the client runs in its own process, answering at
once, so the figures are the transports' own cost on loopback.

    python bench/bench_pull_transport.py [--exchanges 2000] [--size 3000]
"""

from __future__ import annotations

import argparse
import asyncio
import subprocess
import sys
import time

import numpy as np
from fastapi import FastAPI, Request, WebSocket
from fastapi.responses import Response

REPLY = b'{"x":10.0,"y":20.0,"orientation":1,"compute_time":0.0001}'


def server_app(exchanges: int, size: int, results: dict[str, list[float]]) -> FastAPI:
    app = FastAPI()
    payload = b'{"pad":"' + b"0" * max(0, size - 10) + b'"}'
    state: dict[str, asyncio.Queue[bytes]] = {}

    @app.websocket("/ws")
    async def ws_endpoint(ws: WebSocket) -> None:
        await ws.accept()
        times = results.setdefault("websocket", [])
        for _ in range(exchanges):
            t0 = time.perf_counter()
            await ws.send_bytes(payload)
            await ws.receive_bytes()
            times.append(time.perf_counter() - t0)
        await ws.close()

    @app.post("/poll")
    async def poll(request: Request) -> Response:
        answers = state.setdefault("answers", asyncio.Queue())
        body = await request.body()
        if body:
            answers.put_nowait(body)
        nxt = await state.setdefault("requests", asyncio.Queue()).get()
        return Response(nxt, media_type="application/json")

    @app.post("/drive-poll")
    async def drive_poll() -> Response:
        requests, answers = (
            state.setdefault("requests", asyncio.Queue()),
            state.setdefault("answers", asyncio.Queue()),
        )
        times = results.setdefault("long-poll", [])
        for _ in range(exchanges):
            t0 = time.perf_counter()
            requests.put_nowait(payload)
            await answers.get()
            times.append(time.perf_counter() - t0)
        requests.put_nowait(b"STOP")
        return Response(b"{}", media_type="application/json")

    return app


def client(kind: str, url: str) -> None:
    if kind == "websocket":
        from websockets.sync.client import connect

        with connect(url.replace("http", "ws") + "/ws", compression=None, max_size=None) as ws:
            import socket

            ws.socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            try:
                while True:
                    ws.recv()
                    ws.send(REPLY)
            except Exception:  # noqa: BLE001 - the server closed: done
                return
    from robobpp.client import wire

    host, port = url.removeprefix("http://").split(":")
    conn = wire.Connection(host, int(port))
    answer = b""
    headers = [("Content-Type", "application/json")]
    while True:
        got = conn.request("POST", "/poll", headers, answer, time.monotonic() + 60, 1 << 20)
        if got.body == b"STOP":
            return
        answer = REPLY


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--exchanges", type=int, default=2000)
    parser.add_argument("--size", type=int, default=3000, help="request bytes (an /act of ~20 placed boxes)")
    parser.add_argument("--client", choices=("websocket", "long-poll"), help=argparse.SUPPRESS)
    parser.add_argument("--url", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.client:
        client(args.client, args.url)
        return

    import httpx

    from robobpp.client.serve import BackgroundServer

    results: dict[str, list[float]] = {}
    with BackgroundServer(server_app(args.exchanges, args.size, results)) as server:
        for kind in ("websocket", "long-poll", "websocket", "long-poll"):  # interleaved: drift hits both
            proc = subprocess.Popen([sys.executable, __file__, "--client", kind, "--url", server.url])
            if kind == "long-poll":
                time.sleep(1.0)  # the client's first poll is waiting
                httpx.post(server.url + "/drive-poll", timeout=600)
            proc.wait(timeout=600)
    print(f"{'transport':10s} {'exchanges':>9s} {'p50 ms':>8s} {'p95 ms':>8s} {'mean ms':>8s}")
    for kind, times in results.items():
        ms = np.array(times[50:]) * 1000.0  # the first exchanges warm caches up
        print(
            f"{kind:10s} {len(ms):9d} {np.percentile(ms, 50):8.3f} {np.percentile(ms, 95):8.3f} {ms.mean():8.3f}"
        )


if __name__ == "__main__":
    main()
