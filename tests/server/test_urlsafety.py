"""Policy URL checks (docs/server.md, "Hostile participants"): what the workers may call."""

from __future__ import annotations

import pytest

from robobpp.server.urlsafety import UnsafeURLError, check_policy_url, parse_url


@pytest.mark.parametrize(
    "url",
    [
        "ftp://example.com",
        "file:///etc/passwd",
        "http://",
        "javascript:alert(1)",
        "http://user:pw@example.com",
        "http://example.com/?q=1",
        "http://h:99999/",
        "http://example.com/#x",
        "http://" + "a" * 2100,
    ],
)
def test_malformed_urls_are_refused(url: str) -> None:
    with pytest.raises(UnsafeURLError) as err:
        parse_url(url)
    assert err.value.kind == "policy-url-invalid"


@pytest.mark.parametrize(
    "url",
    [
        "http://127.0.0.1:9000",
        "http://localhost:9000",
        "http://10.1.2.3",
        "http://192.168.1.1",
        "http://172.16.0.1",
        "http://169.254.10.10",
        "http://[::1]:9000",
        "http://[fe80::1]",
        "http://[::ffff:127.0.0.1]",
        "http://100.64.0.1",
        "http://0.0.0.0",
    ],
)
def test_inside_addresses_are_refused_by_default(url: str) -> None:
    with pytest.raises(UnsafeURLError) as err:
        check_policy_url(url, allow_private=False)
    assert err.value.kind == "policy-url-forbidden"


@pytest.mark.parametrize("url", ["http://169.254.169.254/latest", "http://[fd00:ec2::254]", "http://0.0.0.0"])
def test_metadata_and_unspecified_addresses_are_refused_even_when_private_is_allowed(url: str) -> None:
    with pytest.raises(UnsafeURLError):
        check_policy_url(url, allow_private=True)


def test_loopback_allowed_when_the_operator_says_so_and_address_is_pinned() -> None:
    checked = check_policy_url("http://127.0.0.1:9000/", allow_private=True)
    assert (
        checked.pinned_ip == "127.0.0.1" and checked.url == "http://127.0.0.1:9000" and checked.port == 9000
    )


def test_public_literal_address_passes() -> None:
    assert check_policy_url("https://8.8.8.8/policy", allow_private=False).pinned_ip == "8.8.8.8"


def test_unresolvable_host_is_unreachable() -> None:
    with pytest.raises(UnsafeURLError) as err:
        check_policy_url("http://does-not-exist.invalid", allow_private=False)
    assert err.value.kind == "policy-unreachable"
