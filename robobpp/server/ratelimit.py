"""Failed authentications: after ``max_failures`` within ``window_s``, a client address, a token prefix or a
participant is refused (429) until its oldest failure leaves the window.

Tokens are random (32 bytes), so guessing one is hopeless anyway; the limit keeps a flood of wrong tokens
(258 sign-ins and 448 bearer attempts a second before it) from costing a token look-up each, and makes a
leaked prefix or a weak operator-chosen admin token no easier to complete. Only failures count: a
participant's scripts with a valid token are never slowed. The tables live in the API process.

A wrong token counts three times, each in a table of its own (one kind cannot push another out):

- against the client's address: the peer's, or behind a reverse proxy the address the proxy saw, taken from
  ``X-Forwarded-For`` only when the peer is one of ``ROBOBPP_TRUSTED_PROXIES`` (uvicorn's
  ``forwarded_allow_ips``, set from it in :func:`robobpp.server.connections.server_config`). Before, the
  deployment guide recommended trusting every peer (``*``): a client that rotated the header got 60 wrong
  API tokens and 30 wrong sign-ins answered 401, never 429;
- against the token's prefix (its first :data:`PREFIX_CHARS` characters, ``rbp_`` and 6 random ones, the part
  the pages list): completing one known prefix is limited whatever the addresses;
- against the participant whose live token has that prefix: all of one participant's prefixes together.

The last two are checked before the look-up, as the address is: a correct token with a refused prefix
waits too (else trying the right one would tell it apart). Only the participant and the operator see a
token's prefix, so only they could lock it.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque

#: Keys remembered at most per table (the oldest forgotten first): a spoofed-address flood cannot grow it.
MAX_ADDRESSES = 100_000
#: Characters of a token that name its prefix (``rbp_`` and 6 random ones: services/accounts.py).
PREFIX_CHARS = 10
#: The prefix every API token starts with; other strings (the admin token, garbage) have no prefix key.
TOKEN_PREFIX = "rbp_"


class FailureLimit:
    def __init__(self, max_failures: int = 10, window_s: float = 60.0) -> None:
        self.max_failures = max_failures
        self.window_s = window_s
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self._lock = threading.Lock()

    def retry_after(self, address: str, now: float | None = None) -> float:
        """Seconds until ``address`` (any key) may try again (0: it may now)."""
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


def token_prefix(token: str) -> str | None:
    """The prefix key of an API token (``None`` for anything that is not one)."""
    return token[:PREFIX_CHARS] if token.startswith(TOKEN_PREFIX) else None


class AuthLimits:
    """The three tables of wrong tokens: per client address, per token prefix, per participant."""

    def __init__(self, max_failures: int = 10, window_s: float = 60.0) -> None:
        self.addresses = FailureLimit(max_failures, window_s)
        self.prefixes = FailureLimit(max_failures, window_s)
        self.participants = FailureLimit(max_failures, window_s)
        #: Prefixes of live tokens that failed, and their participant (bounded like the tables).
        self._owners: OrderedDict[str, int] = OrderedDict()
        self._lock = threading.Lock()

    def retry_after(self, address: str, token: str = "", now: float | None = None) -> float:
        """Seconds until this address may present this token (0: now)."""
        waits = [self.addresses.retry_after(address, now)]
        prefix = token_prefix(token)
        if prefix is not None:
            waits.append(self.prefixes.retry_after(prefix, now))
            with self._lock:
                owner = self._owners.get(prefix)
            if owner is not None:
                waits.append(self.participants.retry_after(str(owner), now))
        return max(waits)

    def failed(
        self, address: str, token: str = "", participant_id: int | None = None, now: float | None = None
    ) -> None:
        """Count a wrong token; ``participant_id``: whose live token has the same prefix, if anyone's."""
        self.addresses.failed(address, now)
        prefix = token_prefix(token)
        if prefix is None:
            return
        self.prefixes.failed(prefix, now)
        if participant_id is not None:
            with self._lock:
                self._owners[prefix] = participant_id
                self._owners.move_to_end(prefix)
                while len(self._owners) > MAX_ADDRESSES:
                    self._owners.popitem(last=False)
            self.participants.failed(str(participant_id), now)


def client_address(request: object) -> str:
    client = getattr(request, "client", None)
    return str(client.host) if client is not None and client.host else "unknown"
