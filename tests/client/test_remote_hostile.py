"""Hostile policy servers end the episode with a precise reason; the caller never hangs or leaks."""

from __future__ import annotations

import pytest

from robobpp.client.remote import RemotePolicy
from robobpp.core import EpisodeSpec
from robobpp.episode import run_episode
from tests.client.hostile import HostileServer

#: mode → (termination reason, words the recorded detail must contain)
CASES: dict[str, tuple[str, str]] = {
    "nan": ("protocol_violation", "field 'x': input should be a finite number"),
    "inf": ("protocol_violation", "field 'y': input should be a finite number"),
    "negative": ("out_of_bounds", "outside the container"),
    "huge": ("protocol_violation", "field 'x': input should be less than or equal to 10000"),
    "wrong_type": ("protocol_violation", "field 'x': input should be a valid number (got '0')"),
    "bool_orientation": ("protocol_violation", "field 'orientation': input should be a valid integer"),
    "bad_orientation": ("protocol_violation", "field 'orientation': input should be less than or equal to 1"),
    "extra": ("protocol_violation", "unknown field 'z'"),
    "missing": ("protocol_violation", "missing field 'orientation'"),
    "partial_null": ("protocol_violation", "all numbers (a placement) or all null"),
    "not_object": ("protocol_violation", "must be a JSON object"),
    "invalid_json": ("protocol_violation", "not valid JSON"),
    "negative_compute": ("protocol_violation", "field 'compute_time'"),
    "big": ("protocol_violation", "larger than the 65536-byte cap (Content-Length 10000009)"),
    "big_chunked": ("protocol_violation", "larger than the 65536-byte cap"),
    "slow": ("policy_timeout", "no complete answer to POST /act (step 0) within 0.5 s"),
    "drip": ("policy_timeout", "no complete answer to POST /act (step 0) within 0.5 s"),
    "drop": ("policy_error", "the connection broke during POST /act (step 0)"),
    "garbage": ("policy_error", "the connection broke during POST /act (step 0)"),
    "error500": ("policy_error", 'POST /act (step 0) failed with HTTP 500: \'{"error": "kaput"}\''),
    "html": ("protocol_violation", "Content-Type 'text/html', expected application/json"),
    "gzip": ("protocol_violation", "Content-Encoding 'gzip'"),
    "redirect": (
        "protocol_violation",
        "redirect (HTTP 302 to 'http://169.254.169.254/act'); redirects are not",
    ),
    "wrong_protocol": ("protocol_violation", "field 'protocol'"),
    "reset_500": ("policy_error", "POST /reset failed with HTTP 500: 'boom at reset'"),
}


@pytest.mark.parametrize("mode", sorted(CASES))
def test_hostile_server_ends_episode_with_precise_reason(
    mode: str, hostile: HostileServer, small_spec: EpisodeSpec
) -> None:
    reason, words = CASES[mode]
    policy = RemotePolicy(f"{hostile.url}/{mode}", step_timeout_s=0.5)
    result = run_episode(small_spec, policy, "math")
    assert result.termination == reason, result.termination_detail
    assert words in result.termination_detail
    assert result.boxes_placed == 0
    # The caller released everything: the server sees every socket closed.
    assert not policy.connected
    assert hostile.wait_all_closed(), f"{hostile.open_connections} connection(s) still open"


def test_no_placement_answer_ends_episode_and_keeps_compute_time(
    hostile: HostileServer, small_spec: EpisodeSpec
) -> None:
    result = run_episode(small_spec, RemotePolicy(f"{hostile.url}/no_placement"), "math")
    assert result.termination == "no_feasible_placement"
    assert result.steps[0].action is None


def test_good_server_completes_and_reports_compute_time(
    hostile: HostileServer, small_spec: EpisodeSpec
) -> None:
    result = run_episode(small_spec, RemotePolicy(f"{hostile.url}/compute_time"), "math")
    assert result.termination == "completed", result.termination_detail
    assert [s.compute_time for s in result.steps] == [0.125] * 4
    # Decision time is what the caller measured, not what the policy said.
    assert all(s.decision_time != 0.125 for s in result.steps)


def test_one_connection_is_kept_alive_for_the_whole_episode(small_spec: EpisodeSpec) -> None:
    with HostileServer() as server:
        result = run_episode(small_spec, RemotePolicy(f"{server.url}/good"), "math")
        assert result.termination == "completed"
        assert server.total_connections == 1
        assert [r[1] for r in server.requests] == [
            "/good/info",
            "/good/reset",
            "/good/act",
            "/good/act",
            "/good/act",
            "/good/act",
            "/good/close",
        ]
        assert server.wait_all_closed()


def test_policy_is_reusable_across_episodes(hostile: HostileServer, small_spec: EpisodeSpec) -> None:
    policy = RemotePolicy(f"{hostile.url}/good")
    first = run_episode(small_spec, policy, "math")
    second = run_episode(small_spec, policy, "math")
    assert first.termination == second.termination == "completed"
    assert not policy.connected


def test_pinned_address_reaches_the_vetted_ip_without_dns(
    hostile: HostileServer, small_spec: EpisodeSpec
) -> None:
    port = hostile.server_address[1]
    # .invalid never resolves (RFC 2606): only the pinned address can make this work.
    policy = RemotePolicy(f"http://policy.invalid:{port}/good", resolved_ip="127.0.0.1")
    result = run_episode(small_spec, policy, "math")
    assert result.termination == "completed", result.termination_detail
    assert hostile.requests[-1][2]["host"] == f"policy.invalid:{port}"


def test_unreachable_server_is_a_policy_error(small_spec: EpisodeSpec) -> None:
    with HostileServer() as server:
        url = server.url
    result = run_episode(small_spec, RemotePolicy(f"{url}/good", connect_timeout_s=1), "math")
    assert result.termination == "policy_error"
    assert "cannot connect" in result.termination_detail


def test_episode_time_limit_bounds_a_slow_policy(hostile: HostileServer, small_spec: EpisodeSpec) -> None:
    policy = RemotePolicy(f"{hostile.url}/slow", step_timeout_s=30, episode_timeout_s=0.5)
    result = run_episode(small_spec, policy, "math")
    assert result.termination == "episode_timeout"
    assert "0.5 s episode limit" in result.termination_detail


@pytest.mark.parametrize(
    "url", ["ftp://x/", "http://", "127.0.0.1:9000", "http://h:1/p?q=1", "http://h:1/#f"]
)
def test_malformed_urls_are_refused_up_front(url: str) -> None:
    with pytest.raises(ValueError, match="policy URL"):
        RemotePolicy(url)


def test_pinned_address_must_be_an_ip() -> None:
    with pytest.raises(ValueError):
        RemotePolicy("http://example.org", resolved_ip="example.org")
