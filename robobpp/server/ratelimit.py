"""Failed authentications per client address: after ``max_failures`` within ``window_s``, an address is refused
(429) until its oldest failure leaves the window.

Tokens are random (32 bytes), so guessing one is hopeless anyway; the limit keeps a flood of wrong tokens
(258 sign-ins and 448 bearer attempts a second before it) from costing a token look-up each, and makes a
leaked prefix or a weak operator-chosen admin token no easier to complete. Only failures count: a
participant's scripts with a valid token are never slowed. The table lives in the API process (one process
serves the API; behind a proxy, uvicorn's ``FORWARDED_ALLOW_IPS`` gives the client's address).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque

#: Addresses remembered at most (the oldest forgotten first): a spoofed-address flood cannot grow the table.
MAX_ADDRESSES = 100_000


class FailureLimit:
    def __init__(self, max_failures: int = 10, window_s: float = 60.0) -> None:
        self.max_failures = max_failures
        self.window_s = window_s
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self._lock = threading.Lock()

    def retry_after(self, address: str, now: float | None = None) -> float:
        """Seconds until ``address`` may try again (0: it may now)."""
        now = time.monotonic() if now is None else now
        with self._lock:
            failures = self._failures.get(address)
            if failures is None:
                return 0.0
            while failures and failures[0] <= now - self.window_s:
                failures.popleft()
            if not failures:
                del self._failures[address]
                return 0.0
            if len(failures) < self.max_failures:
                return 0.0
            return max(0.0, failures[0] + self.window_s - now)

    def failed(self, address: str, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        with self._lock:
            failures = self._failures.setdefault(address, deque(maxlen=self.max_failures))
            failures.append(now)
            self._failures.move_to_end(address)
            while len(self._failures) > MAX_ADDRESSES:
                self._failures.popitem(last=False)


def client_address(request: object) -> str:
    client = getattr(request, "client", None)
    return str(client.host) if client is not None and client.host else "unknown"
