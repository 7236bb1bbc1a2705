"""A slow-drip policy server (run as a process): ``GET /info`` answers headers that promise 60,000 bytes,
then one byte every ``--interval`` seconds until the caller gives up. ``GET /stats`` answers at once with
the connection counts (open now, most open at once, total), so a test can see how many probes it got."""

from __future__ import annotations

import argparse
import asyncio
import json

stats = {"open": 0, "max_open": 0, "total": 0}


async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, interval: float) -> None:
    try:
        head = await reader.readuntil(b"\r\n\r\n")
    except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError):
        writer.close()
        return
    if head.startswith(b"GET /stats"):
        body = json.dumps(stats).encode()
        writer.write(
            b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nConnection: close\r\n"
            b"Content-Length: %d\r\n\r\n%s" % (len(body), body)
        )
        await writer.drain()
        writer.close()
        return
    stats["open"] += 1
    stats["total"] += 1
    stats["max_open"] = max(stats["max_open"], stats["open"])
    # The caller hanging up shows as EOF on the read side: count the connection closed at once.
    hung_up = asyncio.ensure_future(reader.read(1))
    try:
        writer.write(b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: 60000\r\n\r\n{")
        for _ in range(60000):
            await writer.drain()
            done, _ = await asyncio.wait({hung_up}, timeout=interval)
            if done:
                break
            writer.write(b" ")
    except ConnectionError:
        pass
    finally:
        stats["open"] -= 1
        hung_up.cancel()
        writer.close()


async def main(port: int, interval: float) -> None:
    server = await asyncio.start_server(lambda r, w: handle(r, w, interval), "127.0.0.1", port, backlog=1024)
    async with server:
        await server.serve_forever()


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("port", type=int)
    parser.add_argument("--interval", type=float, default=0.5)
    args = parser.parse_args()
    asyncio.run(main(args.port, args.interval))
