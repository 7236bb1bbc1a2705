"""The submit-time policy check, kept off the request path and bounded (docs/server.md, "Hostile participants and the threat model of the private split").

A submission's URL is resolved and its ``GET /info`` probed before anything is written, and that outbound
call is the one place where a stranger's server can make the API wait. So it never runs on the request
thread pool that every other route shares: the (async) submit route hands it to this gate, which runs it
on a small pool of its own under

* a hard deadline on the whole exchange (DNS, connect, send, every byte of the answer) — the wire client
  enforces it; the gate waits at most the same time again for a free slot;
* a per-participant limit (probes in flight per API token): the rest are refused at once with 429, so
  one participant cannot occupy the pool;
* an overall limit (the pool size): when every slot stays busy past the wait, 429 with Retry-After.

A flood of slow policies therefore costs at most ``concurrency`` threads for ``deadline`` seconds each,
while ``/healthz``, the leaderboards and the pages keep their usual latency.
"""

from __future__ import annotations

import asyncio
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from robobpp.server.problems import ProblemError

T = TypeVar("T")


class ProbeGate:
    """Bounded, deadline-guarded execution of outbound checks, keyed by participant.

    Used from the app's event loop: the counters need no lock, and waiting for a slot holds no thread. The
    pool and the semaphore are made on first use (and again for a new loop: test clients start one each).
    """

    def __init__(self, concurrency: int, per_participant: int, deadline_s: float) -> None:
        self.concurrency = concurrency
        self.per_participant = per_participant
        self.deadline_s = deadline_s
        self._pool: ThreadPoolExecutor | None = None
        self._slots: tuple[asyncio.AbstractEventLoop, asyncio.Semaphore] | None = None
        self._in_flight: Counter[str] = Counter()

    def _resources(self) -> tuple[ThreadPoolExecutor, asyncio.Semaphore]:
        loop = asyncio.get_running_loop()
        if self._slots is None or self._slots[0] is not loop:
            self._slots = (loop, asyncio.Semaphore(self.concurrency))
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=self.concurrency, thread_name_prefix="robobpp-probe")
        return self._pool, self._slots[1]

    def _busy(self, detail: str) -> ProblemError:
        return ProblemError(
            429,
            "probe-busy",
            "Too many policy checks",
            detail,
            headers={"Retry-After": str(max(1, round(self.deadline_s)))},
        )

    async def run(self, key: str, fn: Callable[[], T]) -> T:
        """Run ``fn`` (a blocking check that honours :attr:`deadline_s`) on the gate's own pool."""
        if self._in_flight[key] >= self.per_participant:
            raise self._busy(
                f"at most {self.per_participant} policy check(s) at a time per participant; "
                "wait for the answer to the previous submission"
            )
        self._in_flight[key] += 1
        pool, slots = self._resources()
        try:
            try:
                await asyncio.wait_for(slots.acquire(), self.deadline_s)
            except TimeoutError:
                raise self._busy("the service is checking many policies right now; retry shortly") from None
            try:
                # The check keeps its own deadline on the exchange; this bounds what it cannot (DNS lookup).
                future = asyncio.get_running_loop().run_in_executor(pool, fn)
                return await asyncio.wait_for(future, 2 * self.deadline_s + 1)
            except TimeoutError:
                raise ProblemError(
                    422,
                    "policy-unreachable",
                    "Policy unreachable",
                    f"the policy URL could not be checked within {2 * self.deadline_s + 1:g} s",
                ) from None
            finally:
                slots.release()
        finally:
            self._in_flight[key] -= 1
            if self._in_flight[key] <= 0:
                del self._in_flight[key]

    def in_flight(self) -> int:
        return sum(self._in_flight.values())

    def shutdown(self) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)
