"""Policy URL safety (DESIGN.md §6): the workers call URLs that strangers give us.

Refused: non-http(s) schemes, credentials in the URL, hosts that resolve to private, loopback,
link-local, multicast, reserved or unspecified addresses (unless the operator allows private addresses)
and cloud metadata endpoints (always). The host is resolved once, at submission, and the address is
pinned: workers connect to that address (:class:`PinnedTransport`), so a DNS answer that changes later
(rebinding) cannot steer them inside the network. Redirects are never followed.
"""

from __future__ import annotations

import ipaddress
import socket
from dataclasses import dataclass
from urllib.parse import urlsplit

import httpx

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
        ip = ipaddress.ip_address(info[4][0].split("%")[0])
        if ip not in addresses:
            addresses.append(ip)
    for ip in addresses:  # every answer must be acceptable: a mixed answer is a rebinding trick
        problem = _address_problem(ip, allow_private)
        if problem:
            raise UnsafeURLError("policy-url-forbidden", f"the policy host {host!r} resolves to {problem} ({ip}); "
                                 "the service only calls public addresses")  # fmt: skip
    if not addresses:
        raise UnsafeURLError("policy-unreachable", f"the policy host {host!r} has no address")
    return CheckedURL(url.rstrip("/"), host, port, str(addresses[0]))


class PinnedTransport(httpx.HTTPTransport):
    """Connects to the pinned address whatever the host name resolves to now; TLS still checks the name."""

    def __init__(self, pinned_ip: str, host: str, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.pinned_ip = pinned_ip
        self.host = host

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        if request.url.host == self.host:
            ip = self.pinned_ip
            request.url = request.url.copy_with(host=ip)
            request.extensions = {**request.extensions, "sni_hostname": self.host}
        return super().handle_request(request)


def probe_policy(
    checked: CheckedURL, *, secret: str | None = None, timeout_s: float = 5.0, cap_bytes: int = 64 * 1024
) -> dict[str, object]:
    """Signed ``GET {url}/info`` through the pinned address, no redirects, capped body; raise if unusable."""
    from robobpp.protocol import signed_headers

    headers = {"Host": _host_header(checked)}
    if secret is not None:
        headers.update(signed_headers(secret, b""))
    transport = PinnedTransport(checked.pinned_ip, checked.host)
    try:
        with (
            httpx.Client(transport=transport, timeout=timeout_s, follow_redirects=False) as client,
            client.stream("GET", checked.url + "/info", headers=headers) as r,
        ):
            body = b""
            for chunk in r.iter_bytes():
                body += chunk
                if len(body) > cap_bytes:
                    raise UnsafeURLError("policy-unreachable", "the policy's /info answer is too large")
    except httpx.HTTPError as exc:
        raise UnsafeURLError("policy-unreachable",
                             f"the policy at {checked.url} did not answer GET /info: {type(exc).__name__}") from None  # fmt: skip
    if r.status_code == 401:
        raise UnsafeURLError("policy-unreachable", "the policy refused our signed GET /info (HTTP 401): "
                             "is the submission's secret the one the policy server checks?")  # fmt: skip
    if r.status_code != 200:
        raise UnsafeURLError("policy-unreachable", f"the policy's GET /info answered HTTP {r.status_code}")
    try:
        info = httpx.Response(200, content=body).json()
    except ValueError:
        raise UnsafeURLError("policy-unreachable", "the policy's GET /info answer is not JSON") from None
    if not isinstance(info, dict):
        raise UnsafeURLError("policy-unreachable", "the policy's GET /info answer is not a JSON object")
    protocol = info.get("protocol")
    if protocol is not None and protocol != "robobpp/1":
        raise UnsafeURLError("policy-unreachable", f"the policy speaks {protocol!r}, not robobpp/1")
    return info


def _host_header(checked: CheckedURL) -> str:
    default = 443 if checked.url.startswith("https") else 80
    return checked.host if checked.port == default else f"{checked.host}:{checked.port}"
