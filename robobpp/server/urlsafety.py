"""Policy URL safety (docs/server.md, "Hostile participants"): the workers call URLs that strangers give us.

Refused: non-http(s) schemes, credentials in the URL, hosts that resolve to private, loopback,
link-local, multicast, reserved or unspecified addresses (unless the operator allows private addresses)
and cloud metadata endpoints (always). The host is resolved once, at submission, and the address is
pinned: workers and the submit probe connect to that address, so a DNS answer that changes later
(rebinding) cannot steer them inside the network. Redirects are never followed.
"""

from __future__ import annotations

import ipaddress
import socket
from dataclasses import dataclass
from urllib.parse import urlsplit

#: Cloud metadata services: refused even when private addresses are allowed.
METADATA_ADDRESSES = frozenset(
    ipaddress.ip_address(a) for a in ("169.254.169.254", "169.254.170.2", "100.100.100.200", "fd00:ec2::254")
)
BUILTIN_SCHEME = "builtin:"


class UnsafeURLError(ValueError):
    """The URL is malformed or points somewhere the workers must not go. ``kind`` names the problem."""

    def __init__(self, kind: str, detail: str) -> None:
        super().__init__(detail)
        self.kind = kind
        self.detail = detail


@dataclass(frozen=True, slots=True)
class CheckedURL:
    url: str
    host: str
    port: int
    pinned_ip: str


def _address_problem(ip: ipaddress.IPv4Address | ipaddress.IPv6Address, allow_private: bool) -> str | None:
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    if ip in METADATA_ADDRESSES:
        return "a cloud metadata address"
    if ip.is_unspecified or ip.is_multicast or ip.is_reserved:
        return "an unspecified, multicast or reserved address"
    if allow_private:
        return None
    if ip.is_loopback:
        return "a loopback address"
    if ip.is_link_local:
        return "a link-local address"
    if ip.is_private or not ip.is_global:
        return "a private address"
    return None


def parse_url(url: str) -> tuple[str, str, int]:
    """(scheme, host, port) of an http(s) URL, or :class:`UnsafeURLError`."""
    if len(url) > 2048:
        raise UnsafeURLError("policy-url-invalid", "the policy URL is longer than 2048 characters")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        raise UnsafeURLError("policy-url-invalid", f"the policy URL is malformed: {exc}") from None
    if parts.scheme not in ("http", "https"):
        raise UnsafeURLError("policy-url-invalid", "the policy URL must start with http:// or https://")
    if not parts.hostname:
        raise UnsafeURLError("policy-url-invalid", "the policy URL has no host")
    if parts.username or parts.password:
        raise UnsafeURLError("policy-url-invalid", "the policy URL must not carry credentials")
    if parts.query or parts.fragment:
        raise UnsafeURLError("policy-url-invalid", "the policy URL must not have a query or fragment")
    return parts.scheme, parts.hostname, port or (443 if parts.scheme == "https" else 80)


def check_policy_url(url: str, *, allow_private: bool) -> CheckedURL:
    """Validate and resolve ``url`` once; the first acceptable address is pinned."""
    _scheme, host, port = parse_url(url)
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (OSError, UnicodeError) as exc:
        raise UnsafeURLError(
            "policy-unreachable", f"the policy host {host!r} does not resolve: {exc}"
        ) from None
    addresses = []
    for info in infos:
        ip = ipaddress.ip_address(str(info[4][0]).split("%")[0])
        if ip not in addresses:
            addresses.append(ip)
    for ip in addresses:  # every answer must be acceptable: a mixed answer is a rebinding trick
        problem = _address_problem(ip, allow_private)
        if problem:
            raise UnsafeURLError(
                "policy-url-forbidden",
                f"the policy host {host!r} resolves to {problem} ({ip}); "
                "the service only calls public addresses",
            )
    if not addresses:
        raise UnsafeURLError("policy-unreachable", f"the policy host {host!r} has no address")
    return CheckedURL(url.rstrip("/"), host, port, str(addresses[0]))


def probe_policy(
    checked: CheckedURL, *, secret: str | None = None, timeout_s: float = 5.0, cap_bytes: int = 64 * 1024
) -> dict[str, object]:
    """Signed ``GET {url}/info`` through the pinned address; raise :class:`UnsafeURLError` if unusable.

    The same check as ``robobpp protocol check`` (:meth:`RemotePolicy.fetch_info`): one hard deadline on
    the whole exchange (connect, send, every byte of the answer), a size cap, no redirects, the strict
    ``InfoResponse`` model (``protocol`` must be ``robobpp/1``) and, with a secret, a signed answer.
    """
    from robobpp.client.remote import RemotePolicy, SignatureMismatch
    from robobpp.policies.base import PolicyError

    policy = RemotePolicy(
        checked.url,
        secret,
        step_timeout_s=timeout_s,
        connect_timeout_s=timeout_s,
        max_response_bytes=cap_bytes,
        resolved_ip=checked.pinned_ip,
        check_info=False,
    )
    try:
        info = policy.fetch_info()
    except SignatureMismatch as exc:  # reached, and it answered: only the secrets disagree
        raise UnsafeURLError("policy-signature", signature_advice(checked.url, secret, exc)) from None
    except PolicyError as exc:
        raise UnsafeURLError("policy-unreachable", f"GET {checked.url}/info: {exc.detail}") from None
    finally:
        policy.close()
    return info.model_dump()


def signature_advice(url: str, secret: str | None, exc: object) -> str:
    """What is wrong with the secrets of a submission whose policy answered ``/info``, and what to do."""
    from robobpp.client.remote import SignatureMismatch

    assert isinstance(exc, SignatureMismatch)
    check = f"`robobpp protocol check {url} --secret ...` tests a secret before submitting"
    if exc.refused and secret is None:
        what = (
            "the policy server requires signed requests, and this submission has no secret: submit "
            "with the secret the policy server was started with (--secret or ROBOBPP_POLICY_SECRET)"
        )
    elif exc.refused:
        what = (
            "the policy server refused this submission's signature: its secret is not the one the policy "
            "server was started with; submit with that secret (--secret or ROBOBPP_POLICY_SECRET)"
        )
    else:
        what = (
            "the policy server's answer is not signed with this submission's secret: start the policy "
            "server with the same secret (robobpp policy serve --secret, serve(policy, secret=...)) or "
            "submit without one"
        )
    return f"GET {url}/info answered, but {what}; {check} ({exc.detail})"
