"""``RemotePolicy``: a policy server speaking ``robobpp/1``, seen by the episode loop as an ordinary policy.

The other side is untrusted: it may be slow, drip bytes, send 10 MB, close the socket, answer HTML or
NaN. Every such failure becomes a :class:`~robobpp.policies.base.PolicyError` whose ``reason`` is a
termination code (``policy_timeout``, ``policy_error``, ``protocol_violation``, ``episode_timeout``) and
whose ``detail`` says in plain words what happened, so the episode ends with a recorded reason.

Each exchange runs under one hard deadline over a single keep-alive connection
(:mod:`robobpp.client.wire`); any failure closes that connection, and :meth:`RemotePolicy.close`
always leaves no socket open.
"""

from __future__ import annotations

import contextlib
import ipaddress
import json
import statistics
import time
from collections import deque
from typing import Any, Protocol, TypeVar
from urllib.parse import urlsplit

from pydantic import BaseModel, ValidationError

from robobpp import __version__
from robobpp import protocol as P
from robobpp.client import wire
from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.policies.base import PolicyError

POLICY_TIMEOUT = "policy_timeout"
POLICY_ERROR = "policy_error"
PROTOCOL_VIOLATION = "protocol_violation"
EPISODE_TIMEOUT = "episode_timeout"

#: An answer is a few hundred bytes; this leaves room for verbose error bodies and nothing more.
DEFAULT_MAX_RESPONSE_BYTES = 64 * 1024
#: Echo probes kept for the network estimate (their median), and the longest one probe may take.
PROBE_WINDOW = 5
PROBE_TIMEOUT_S = 2.0
M = TypeVar("M", bound=BaseModel)


def label(info: P.InfoResponse) -> str:
    """A served policy's label in results: ``/info``'s name and version ("lowest-first 1.2"); a policy that
    reports no version (the protocol's default "0") is labelled by its name alone, not "dbl 0"."""
    if not info.version or info.version == P.UNREPORTED_VERSION:
        return info.name
    return f"{info.name} {info.version}"


class SignatureMismatch(PolicyError):
    """The evaluator and the policy server disagree on the shared secret: the server refused the request's
    signature (HTTP 401/403), or the answer is unsigned or signed with another key. ``refused`` tells which
    side: True when the server refused the request."""

    def __init__(self, reason: str, detail: str, *, refused: bool) -> None:
        super().__init__(reason, detail)
        self.refused = refused


class Transport(Protocol):
    """How requests reach the policy: :class:`wire.Connection` (push) or the server's pull relay."""

    last_exchange_s: float | None

    @property
    def is_open(self) -> bool: ...

    def request(
        self, method: str, target: str, headers: list[tuple[str, str]], body: bytes, deadline: float, cap: int
    ) -> wire.Answer: ...

    def close(self) -> None: ...


def probe_body(size: int) -> bytes:
    """An echo probe's body: JSON of ``size`` bytes (at least 10), so it travels like the request it times."""
    return b'{"pad":"' + b"0" * max(0, size - 10) + b'"}'


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


def _encode(payload: dict[str, Any]) -> bytes:
    return json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()


class RemotePolicy:
    """A policy behind an HTTP(S) URL, driven through protocol ``robobpp/1``.

    Only ``url`` is required (``load_policy(url)`` relies on that). The server's workers add the
    address they resolved and vetted once (``resolved_ip``): the connection goes there while Host and
    the TLS server name stay the URL's, so DNS cannot change under a running evaluation. Redirects are
    never followed and no proxy from the environment is used.

    The caller measures decision time around :meth:`act`; the policy's self-reported ``compute_time``
    lands in :attr:`Action.compute_time` (informational). With ``probe_network`` each ``/act`` is preceded
    by an echo probe of the same size on the same connection (``POST /echo``; any complete answer, even a
    404, is a sample); :attr:`last_round_trip` is then the act's round trip and
    :attr:`last_network_estimate` the median of the last probes, capped by the fastest act round trip of
    the episode, and the episode loop ranks their difference. :meth:`close` ends the episode on the
    server side and closes the connection; the object can then be reset for another episode.

    ``transport`` replaces the HTTP connection (pull mode: the server's relay to a participant's client);
    the URL then only names the policy.
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
        verify_tls: bool = True,
        check_info: bool = True,
        name: str | None = None,
        probe_network: bool = False,
        transport: Transport | None = None,
    ) -> None:
        parts = urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ValueError(f"policy URL must be http(s)://host[:port][/path], got {url!r}")
        if parts.query or parts.fragment or parts.username or parts.password:
            raise ValueError(f"policy URL must not carry a query, fragment or credentials, got {url!r}")
        try:
            port = parts.port or (443 if parts.scheme == "https" else 80)
        except ValueError:
            raise ValueError(f"policy URL has an invalid port: {url!r}") from None
        for label, value in (("step_timeout_s", step_timeout_s), ("connect_timeout_s", connect_timeout_s)):
            if not value > 0:
                raise ValueError(f"{label} must be > 0, got {value!r}")
        if max_response_bytes < 16:
            raise ValueError(f"max_response_bytes must be at least 16, got {max_response_bytes!r}")
        if resolved_ip is not None:
            resolved_ip = str(ipaddress.ip_address(resolved_ip))  # ValueError on anything but an address
        self.url = url.rstrip("/")
        #: The URL until ``/info`` names the policy (:meth:`fetch_info`), unless ``name`` is given.
        self.name = name or self.url
        self._named = name is not None
        self.secret = secret
        self.step_timeout_s = float(step_timeout_s)
        self.reset_timeout_s = float(reset_timeout_s if reset_timeout_s is not None else step_timeout_s)
        self.connect_timeout_s = float(connect_timeout_s)
        self.close_timeout_s = float(close_timeout_s)
        self.episode_timeout_s = episode_timeout_s
        self.max_response_bytes = int(max_response_bytes)
        self.check_info = check_info
        self.info: P.InfoResponse | None = None
        self._path = parts.path.rstrip("/")
        self._connection: Transport = transport or wire.Connection(
            parts.hostname,
            port,
            connect_to=resolved_ip,
            tls=parts.scheme == "https",
            verify_tls=verify_tls,
            connect_timeout_s=self.connect_timeout_s,
        )
        self.probe_network = probe_network
        self.last_round_trip: float | None = None
        self.last_network_estimate: float | None = None
        self._probes: deque[float] = deque(maxlen=PROBE_WINDOW)
        self._fastest_act = float("inf")
        self._headers = [
            ("Accept", "application/json"),
            ("Accept-Encoding", "identity"),
            ("User-Agent", f"robobpp/{__version__}"),
            (P.PROTOCOL_HEADER, P.PROTOCOL),
        ]
        self._episode_id: str | None = None
        self._episode_deadline: float | None = None

    # ------------------------------------------------------------------ Policy interface

    def reset(self, info: EpisodeInfo) -> None:
        self._episode_id = info.episode_id
        self._probes.clear()
        self._fastest_act = float("inf")
        self._episode_deadline = (
            time.monotonic() + self.episode_timeout_s if self.episode_timeout_s is not None else None
        )
        if self.check_info and self.info is None:
            self.fetch_info()
        self._call("POST", "/reset", P.reset_payload(info), P.EmptyResponse, self.reset_timeout_s)

    def act(self, obs: Observation) -> Action | None:
        self.last_round_trip = self.last_network_estimate = None
        payload = P.act_payload(obs)
        body = _encode(payload)
        if self.probe_network:
            self._probe(len(body))
        answer = self._call(
            "POST", "/act", payload, P.ActResponse, self.step_timeout_s, obs.step, encoded=body
        )
        round_trip = self._connection.last_exchange_s
        if round_trip is not None:
            self.last_round_trip = round_trip
            self._fastest_act = min(self._fastest_act, round_trip)
            if self._probes:  # a slow echo can never make the network look slower than the fastest act
                self.last_network_estimate = min(statistics.median(self._probes), self._fastest_act)
        return P.action_from_response(answer)

    def _probe(self, size: int) -> None:
        """One echo probe of ``size`` bytes; its round trip joins the window. A failed probe is no sample."""
        body = probe_body(size)
        deadline = time.monotonic() + min(self.step_timeout_s, PROBE_TIMEOUT_S)
        if self._episode_deadline is not None:
            deadline = min(deadline, self._episode_deadline)
        try:
            self._connection.request(
                "POST",
                self._path + "/echo",
                self.request_headers(body),
                body,
                deadline,
                self.max_response_bytes,
            )
        except (wire.DeadlineExceeded, wire.ConnectFailed, wire.ConnectionBroke, wire.TooLarge, ValueError):
            return  # the act that follows meets the same connection and reports what is wrong with it
        if self._connection.last_exchange_s is not None:
            self._probes.append(self._connection.last_exchange_s)

    def close(self, reason: str = "completed", *, strict: bool = False) -> None:
        """Tell the server the episode ended, then close the connection.

        Best effort by default (the episode is over either way and its reason already recorded);
        ``strict=True`` raises the :class:`PolicyError` of a bad answer, for the conformance check.
        """
        try:
            if self._episode_id is not None:
                payload = {"episode_id": self._episode_id, "reason": reason[: P.MAX_TEXT]}
                with contextlib.suppress(*(() if strict else (PolicyError,))):
                    self._call(
                        "POST", "/close", payload, P.EmptyResponse, self.close_timeout_s, use_episode=False
                    )
        finally:
            self._episode_id = None
            self._connection.close()

    def fetch_info(self) -> P.InfoResponse:
        """``GET /info``; checks the server speaks ``robobpp/1``."""
        self.info = self._call("GET", "/info", None, P.InfoResponse, self.reset_timeout_s, use_episode=False)
        if not self._named:  # results are labelled by what the policy says it is, not where it runs
            self.name = label(self.info)
        return self.info

    @property
    def connected(self) -> bool:
        """Whether a connection is open (kept alive between the steps of an episode)."""
        return self._connection.is_open

    def request_headers(self, body: bytes) -> list[tuple[str, str]]:
        """The headers of one request with this body: protocol, content type, signature (with a secret)."""
        headers = list(self._headers)
        if body:
            headers.append(("Content-Type", "application/json"))
        if self.secret is not None:
            headers.extend(P.signed_headers(self.secret, body).items())
        return headers

    def __enter__(self) -> RemotePolicy:
        return self

    def __exit__(self, *exc: object) -> None:
        self._connection.close()

    # ------------------------------------------------------------------ plumbing

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
        encoded: bytes | None = None,
    ) -> M:
        what = f"{method} {path}" + (f" (step {step})" if step is not None else "")
        started = time.monotonic()
        deadline, by_episode = started + timeout_s, False
        if use_episode and self._episode_deadline is not None:
            if self._episode_deadline <= started:
                raise PolicyError(
                    EPISODE_TIMEOUT, f"the policy used up its {self.episode_timeout_s:g} s episode time"
                )
            if self._episode_deadline < deadline:
                deadline, by_episode = self._episode_deadline, True
        body = encoded if encoded is not None else b"" if payload is None else _encode(payload)
        headers = self.request_headers(body)
        request_signature = dict(headers).get(P.SIGNATURE_HEADER, "")
        try:
            answer = self._connection.request(
                method, self._path + path, headers, body, deadline, self.max_response_bytes
            )
        except wire.ConnectTimedOut:
            raise PolicyError(
                POLICY_TIMEOUT,
                f"could not connect to {self.url} within {self.connect_timeout_s:g} s ({what})",
            ) from None
        except wire.DeadlineExceeded:
            if by_episode:
                raise PolicyError(
                    EPISODE_TIMEOUT,
                    f"no answer to {what} before the {self.episode_timeout_s:g} s episode limit",
                ) from None
            raise PolicyError(
                POLICY_TIMEOUT, f"no complete answer to {what} within {timeout_s:g} s"
            ) from None
        except wire.ConnectFailed as exc:
            raise PolicyError(POLICY_ERROR, f"cannot connect to {self.url} ({what}): {exc}") from None
        except wire.ConnectionBroke as exc:
            raise PolicyError(POLICY_ERROR, f"the connection broke during {what}: {exc}") from None
        except wire.TooLarge as exc:
            raise PolicyError(
                PROTOCOL_VIOLATION,
                f"the answer to {what} is larger than the {self.max_response_bytes}-byte cap ({exc})",
            ) from None
        parsed = self._parse(what, answer, model)
        if self.secret is not None:
            # The answer must be signed for this very request: a replayed or altered one ends the episode.
            episode_id = str(payload.get("episode_id", "")) if payload else ""
            try:
                P.verify_answer(
                    self.secret,
                    answer.headers,
                    answer.body,
                    episode_id=episode_id,
                    step=payload.get("step") if payload else None,
                    request_signature=request_signature,
                )
            except P.SignatureError as exc:
                raise SignatureMismatch(
                    PROTOCOL_VIOLATION, f"the answer to {what} is refused: {exc}", refused=False
                ) from None
        return parsed

    def _parse(self, what: str, answer: wire.Answer, model: type[M]) -> M:
        status, headers, content = answer.status, answer.headers, answer.body
        if 300 <= status < 400:
            location = headers.get("location", "?")
            raise PolicyError(
                PROTOCOL_VIOLATION,
                f"{what} answered a redirect (HTTP {status} to {_short(location)}); redirects are not followed",
            )
        if status in (401, 403):
            raise SignatureMismatch(
                POLICY_ERROR,
                f"the policy server refused {what} (HTTP {status}): check the shared secret",
                refused=True,
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
