"""``RemotePolicy``: a policy server speaking ``robobpp/1``, seen by the episode loop as an ordinary policy.

The other side is untrusted: it may be slow, drip bytes, send 10 MB, close the socket, answer HTML or
NaN. Every such failure becomes a :class:`~robobpp.policies.base.PolicyError` whose ``reason`` is a
termination code (``policy_timeout``, ``policy_error``, ``protocol_violation``, ``episode_timeout``) and
whose ``detail`` says in plain words what happened, so the episode ends with a recorded reason.

Why asyncio under a synchronous API: httpx's timeouts bound each socket operation, not the whole
exchange, so a server that drips one byte per second would never trip them. Each exchange therefore
runs as a coroutine on a private event loop (in a daemon thread, so it also works where the caller
already runs a loop, e.g. a notebook) under one hard deadline; cancelling it closes the connection.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import socket
import threading
import time
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar
from urllib.parse import urlsplit

import httpx
from pydantic import BaseModel, ValidationError

from robobpp import protocol as P
from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.policies.base import PolicyError

POLICY_TIMEOUT = "policy_timeout"
POLICY_ERROR = "policy_error"
PROTOCOL_VIOLATION = "protocol_violation"
EPISODE_TIMEOUT = "episode_timeout"

#: An answer is a few hundred bytes; this leaves room for verbose error bodies and nothing more.
DEFAULT_MAX_RESPONSE_BYTES = 64 * 1024
#: Extra seconds the calling thread waits for the loop beyond the exchange's own deadline.
_GRACE_S = 5.0

M = TypeVar("M", bound=BaseModel)
T = TypeVar("T")


class _LoopThread:
    """A private asyncio loop in a daemon thread; :meth:`call` runs one coroutine to completion."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self._run, name="robobpp-remote-policy", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.loop.run_forever()

    def call(self, coro: Coroutine[Any, Any, T], wait_s: float) -> T:
        future = asyncio.run_coroutine_threadsafe(coro, self.loop)
        try:
            return future.result(timeout=wait_s)
        except TimeoutError:
            future.cancel()
            raise

    def stop(self) -> None:
        if self.loop.is_closed():
            return
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout=_GRACE_S)
        if not self.thread.is_alive():
            self.loop.close()


def _short(value: object, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def describe_validation(exc: ValidationError) -> str:
    """Every error of a failed validation, in plain words, one clause each."""
    parts: list[str] = []
    for err in exc.errors(include_url=False):
        where = ".".join(str(p) for p in err["loc"])
        kind = err["type"]
        if kind == "json_invalid":
            parts.append(f"the body is not valid JSON ({err.get('ctx', {}).get('error', err['msg'])})")
        elif kind == "extra_forbidden":
            parts.append(f"unknown field {where!r} (unknown fields are refused)")
        elif kind == "missing":
            parts.append(f"missing field {where!r}")
        elif kind == "model_type" and not where:
            parts.append(f"the body must be a JSON object, got {_short(err['input'])}")
        else:
            label = f"field {where!r}" if where else "the body"
            parts.append(f"{label}: {err['msg'].lower()} (got {_short(err['input'])})")
    return "; ".join(parts)


class RemotePolicy:
    """A policy behind an HTTP(S) URL, driven through protocol ``robobpp/1``.

    Only ``url`` is required (``load_policy(url)`` relies on that). The server's workers add the pinned
    address they resolved and vetted once (``resolved_ip``), so DNS cannot change under a running
    evaluation; redirects are never followed. ``transport_factory`` replaces the HTTP transport
    entirely (one is made each time connections are opened).

    The caller measures decision time around :meth:`act`; the policy's self-reported ``compute_time``
    lands in :attr:`Action.compute_time`. :meth:`close` ends the episode on the server side and releases
    every connection; the object can then be reset for another episode.
    """

    def __init__(
        self,
        url: str,
        secret: str | None = None,
        *,
        step_timeout_s: float = 30.0,
        reset_timeout_s: float | None = None,
        connect_timeout_s: float = 5.0,
        close_timeout_s: float = 5.0,
        episode_timeout_s: float | None = None,
        max_response_bytes: int = DEFAULT_MAX_RESPONSE_BYTES,
        resolved_ip: str | None = None,
        transport_factory: Callable[[], httpx.AsyncBaseTransport] | None = None,
        verify_tls: bool = True,
        check_info: bool = True,
        name: str | None = None,
    ) -> None:
        parts = urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ValueError(f"policy URL must be http(s)://host[:port][/path], got {url!r}")
        if parts.query or parts.fragment:
            raise ValueError(f"policy URL must not carry a query or fragment, got {url!r}")
        for label, value in (("step_timeout_s", step_timeout_s), ("connect_timeout_s", connect_timeout_s)):
            if not value > 0:
                raise ValueError(f"{label} must be > 0, got {value!r}")
        if max_response_bytes < 16:
            raise ValueError(f"max_response_bytes must be at least 16, got {max_response_bytes!r}")
        self.url = url.rstrip("/")
        self.name = name or self.url
        self.secret = secret
        self.step_timeout_s = float(step_timeout_s)
        self.reset_timeout_s = float(reset_timeout_s if reset_timeout_s is not None else step_timeout_s)
        self.connect_timeout_s = float(connect_timeout_s)
        self.close_timeout_s = float(close_timeout_s)
        self.episode_timeout_s = episode_timeout_s
        self.max_response_bytes = int(max_response_bytes)
        self.verify_tls = verify_tls
        self.check_info = check_info
        self.transport_factory = transport_factory
        self.info: P.InfoResponse | None = None
        self._host_header: str | None = None
        self._sni: str | None = None
        self._base = self.url
        if resolved_ip is not None:
            ip = ipaddress.ip_address(resolved_ip)  # ValueError on anything but a literal address
            host = f"[{ip}]" if ip.version == 6 else str(ip)
            port = f":{parts.port}" if parts.port else ""
            self._base = f"{parts.scheme}://{host}{port}{parts.path}".rstrip("/")
            self._host_header = parts.netloc.rpartition("@")[2]
            self._sni = parts.hostname
        self._runner: _LoopThread | None = None
        self._client: httpx.AsyncClient | None = None
        self._episode_id: str | None = None
        self._episode_deadline: float | None = None

    # ------------------------------------------------------------------ Policy interface

    def reset(self, info: EpisodeInfo) -> None:
        self._open()
        self._episode_id = info.episode_id
        self._episode_deadline = (
            time.monotonic() + self.episode_timeout_s if self.episode_timeout_s is not None else None
        )
        if self.check_info and self.info is None:
            self.fetch_info()
        self._call("POST", "/reset", P.reset_payload(info), P.EmptyResponse, self.reset_timeout_s)

    def act(self, obs: Observation) -> Action | None:
        self._open()
        answer = self._call("POST", "/act", P.act_payload(obs), P.ActResponse, self.step_timeout_s, obs.step)
        return P.action_from_response(answer)

    def close(self, reason: str = "completed", *, strict: bool = False) -> None:
        """Tell the server the episode ended, then release every connection.

        Best effort by default (the episode is over either way and its reason already recorded);
        ``strict=True`` raises the :class:`PolicyError` of a bad answer, for the conformance check.
        """
        try:
            if self._client is not None and self._episode_id is not None:
                payload = {"episode_id": self._episode_id, "reason": reason[: P.MAX_TEXT]}
                with contextlib.suppress(*(() if strict else (PolicyError,))):
                    self._call(
                        "POST", "/close", payload, P.EmptyResponse, self.close_timeout_s, use_episode=False
                    )
        finally:
            self._episode_id = None
            self._shutdown()

    def fetch_info(self) -> P.InfoResponse:
        """``GET /info``; checks the server speaks ``robobpp/1``."""
        self._open()
        self.info = self._call("GET", "/info", None, P.InfoResponse, self.reset_timeout_s, use_episode=False)
        return self.info

    def __enter__(self) -> RemotePolicy:
        return self

    def __exit__(self, *exc: object) -> None:
        self._shutdown()

    def __del__(self) -> None:  # last resort: never leave a loop thread behind
        with contextlib.suppress(Exception):  # interpreter teardown
            self._shutdown()

    # ------------------------------------------------------------------ plumbing

    def _open(self) -> None:
        if self._runner is not None:
            return
        self._runner = _LoopThread()
        self._runner.call(self._make_client(), _GRACE_S)

    async def _make_client(self) -> None:
        transport = self.transport_factory() if self.transport_factory else None
        if transport is None:
            # Without TCP_NODELAY, Nagle's algorithm and delayed ACKs add ~40 ms to every small request.
            nodelay = [(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)]
            transport = httpx.AsyncHTTPTransport(verify=self.verify_tls, socket_options=nodelay, retries=0)
        self._client = httpx.AsyncClient(
            transport=transport,
            follow_redirects=False,
            verify=self.verify_tls,
            trust_env=False,  # a proxy from the environment would defeat the pinned address
            timeout=httpx.Timeout(self.step_timeout_s, connect=self.connect_timeout_s),
            limits=httpx.Limits(max_connections=2, max_keepalive_connections=1, keepalive_expiry=60.0),
            headers={
                "Accept": "application/json",
                "Accept-Encoding": "identity",
                P.PROTOCOL_HEADER: P.PROTOCOL,
            },
        )

    def _shutdown(self) -> None:
        runner, client = self._runner, self._client
        self._runner = self._client = None
        if runner is None:
            return
        if client is not None:
            with contextlib.suppress(Exception):  # closing must not raise
                runner.call(client.aclose(), _GRACE_S)
        runner.stop()

    def _call(
        self,
        method: str,
        path: str,
        payload: dict[str, Any] | None,
        model: type[M],
        timeout_s: float,
        step: int | None = None,
        *,
        use_episode: bool = True,
    ) -> M:
        what = f"{method} {path}" + (f" (step {step})" if step is not None else "")
        reason_on_timeout = POLICY_TIMEOUT
        if use_episode and self._episode_deadline is not None:
            remaining = self._episode_deadline - time.monotonic()
            if remaining <= 0:
                raise PolicyError(
                    EPISODE_TIMEOUT, f"the policy used up its {self.episode_timeout_s:g} s episode time"
                )
            if remaining < timeout_s:
                timeout_s, reason_on_timeout = remaining, EPISODE_TIMEOUT
        body = (
            b"" if payload is None else json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()
        )
        assert self._runner is not None
        try:
            status, headers, content = self._runner.call(
                self._exchange(method, path, body, timeout_s), timeout_s + _GRACE_S
            )
        except TimeoutError:
            if reason_on_timeout == EPISODE_TIMEOUT:
                raise PolicyError(
                    EPISODE_TIMEOUT,
                    f"no answer to {what} before the {self.episode_timeout_s:g} s episode limit",
                ) from None
            raise PolicyError(
                POLICY_TIMEOUT, f"no complete answer to {what} within {timeout_s:g} s"
            ) from None
        except httpx.ConnectTimeout:
            raise PolicyError(
                POLICY_TIMEOUT,
                f"could not connect to {self.url} within {self.connect_timeout_s:g} s ({what})",
            ) from None
        except httpx.TimeoutException as exc:
            raise PolicyError(POLICY_TIMEOUT, f"{what} timed out: {type(exc).__name__}") from None
        except httpx.ConnectError as exc:
            raise PolicyError(POLICY_ERROR, f"cannot connect to {self.url} ({what}): {exc}") from None
        except httpx.RemoteProtocolError as exc:
            raise PolicyError(
                POLICY_ERROR,
                f"the connection broke during {what}: {exc or 'server closed it without an answer'}",
            ) from None
        except httpx.TransportError as exc:
            raise PolicyError(
                POLICY_ERROR, f"network error during {what}: {type(exc).__name__}: {exc}"
            ) from None
        except _TooLarge as exc:
            raise PolicyError(
                PROTOCOL_VIOLATION,
                f"the answer to {what} is larger than the {self.max_response_bytes}-byte cap ({exc})",
            ) from None
        return self._parse(what, status, headers, content, model)

    def _parse(self, what: str, status: int, headers: httpx.Headers, content: bytes, model: type[M]) -> M:
        if 300 <= status < 400:
            location = headers.get("location", "?")
            raise PolicyError(
                PROTOCOL_VIOLATION,
                f"{what} answered a redirect (HTTP {status} to {_short(location)}); redirects are not followed",
            )
        if status in (401, 403):
            raise PolicyError(
                POLICY_ERROR, f"the policy server refused {what} (HTTP {status}): check the shared secret"
            )
        if status != 200:
            snippet = content[:300].decode("utf-8", "replace")
            raise PolicyError(POLICY_ERROR, f"{what} failed with HTTP {status}: {_short(snippet, 300)}")
        encoding = headers.get("content-encoding", "identity").strip().lower()
        if encoding not in ("", "identity"):
            raise PolicyError(
                PROTOCOL_VIOLATION, f"{what} answered Content-Encoding {_short(encoding)}; send plain JSON"
            )
        ctype = headers.get("content-type", "")
        if ctype.split(";")[0].strip().lower() != "application/json":
            raise PolicyError(
                PROTOCOL_VIOLATION,
                f"{what} answered Content-Type {ctype or 'none'!r}, expected application/json",
            )
        try:
            return model.model_validate_json(content)
        except ValidationError as exc:
            raise PolicyError(
                PROTOCOL_VIOLATION, f"bad answer to {what}: {describe_validation(exc)}"
            ) from None

    async def _exchange(
        self, method: str, path: str, body: bytes, timeout_s: float
    ) -> tuple[int, httpx.Headers, bytes]:
        """One request under a hard deadline; the body is read in chunks and cut off past the cap."""
        assert self._client is not None
        headers = {"Content-Type": "application/json"} if method == "POST" else {}
        if self.secret is not None:
            headers.update(P.signed_headers(self.secret, body))
        if self._host_header is not None:
            headers["Host"] = self._host_header
        extensions = {"sni_hostname": self._sni} if self._sni is not None else None
        request = self._client.build_request(
            method, self._base + path, content=body or None, headers=headers, extensions=extensions
        )
        async with asyncio.timeout(timeout_s):
            response = await self._client.send(request, stream=True)
            try:
                declared = response.headers.get("content-length")
                if declared is not None and declared.isdigit() and int(declared) > self.max_response_bytes:
                    raise _TooLarge(f"Content-Length {declared}")
                chunks: list[bytes] = []
                size = 0
                async for chunk in response.aiter_raw():
                    size += len(chunk)
                    if size > self.max_response_bytes:
                        raise _TooLarge(f"more than {size} bytes sent")
                    chunks.append(chunk)
                return response.status_code, response.headers, b"".join(chunks)
            finally:
                await response.aclose()


class _TooLarge(Exception):
    """The answer passed the response size cap; reading stopped there."""
