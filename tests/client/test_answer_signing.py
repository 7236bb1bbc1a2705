"""Signed answers (protocol.md, "Signing"): bound to episode, step and request; replays end the episode."""

from __future__ import annotations

import hashlib
import hmac
import json
from collections.abc import Iterator

import httpx
import pytest

from robobpp import protocol as P
from robobpp.client.remote import RemotePolicy
from robobpp.client.serve import BackgroundServer, create_policy_app
from robobpp.core import EpisodeSpec
from robobpp.episode import run_episode
from robobpp.policies.dbl import DBL
from tests.client.hostile import HostileServer

SECRET = "answer-secret-42"


@pytest.fixture(scope="module")
def signing_hostile() -> Iterator[HostileServer]:
    with HostileServer(slow_s=1.0, secret=SECRET) as server:
        yield server


def test_sdk_answers_carry_the_documented_hmac() -> None:
    """The bytes of docs/protocol.md, recomputed here with hmac alone, match what serve() sends."""
    body = json.dumps(
        {
            "episode_id": "demo-1",
            "dataset": "diverse",
            "setting": "math",
            "container": {"length": 120, "width": 100, "height": 170},
        }
    ).encode()
    request_headers = P.signed_headers(SECRET, body)
    with BackgroundServer(create_policy_app(DBL(), SECRET)) as server:
        r = httpx.post(server.url + "/reset", content=body, headers=request_headers)
    assert r.status_code == 200, r.text
    ts = r.headers[P.TIMESTAMP_HEADER]
    head = f'["demo-1",null,{ts},"{request_headers[P.SIGNATURE_HEADER]}"]'.encode()
    expected = hmac.new(SECRET.encode(), b"robobpp/1 answer\n" + head + b"\n" + r.content, hashlib.sha256)
    assert r.headers[P.SIGNATURE_HEADER] == expected.hexdigest()
    # Bound to the request: the same answer does not verify for another step or another request.
    signature = request_headers[P.SIGNATURE_HEADER]
    P.verify_answer(SECRET, r.headers, r.content, step=None, episode_id="demo-1", request_signature=signature)
    with pytest.raises(P.SignatureError, match="replayed"):
        P.verify_answer(
            SECRET, r.headers, r.content, step=3, episode_id="demo-1", request_signature=signature
        )
    with pytest.raises(P.SignatureError, match="replayed"):
        P.verify_answer(
            SECRET,
            r.headers,
            r.content,
            step=None,
            episode_id="demo-1",
            request_signature=P.signed_headers(SECRET, b"{}")[P.SIGNATURE_HEADER],
        )


def test_signed_sdk_server_completes_an_episode(small_spec: EpisodeSpec) -> None:
    with BackgroundServer(create_policy_app(DBL(), SECRET)) as server:
        result = run_episode(small_spec, RemotePolicy(server.url, SECRET), "math")
    assert result.termination == "completed", result.termination_detail
    assert result.boxes_placed == len(small_spec.boxes)


CASES = {
    "replay": "does not match this request's episode, step and body",
    "wrong_episode": "does not match this request's episode, step and body",
    "resign_old": "stale timestamp",
    "unsigned": "missing X-Robobpp-Timestamp or X-Robobpp-Signature",
}


@pytest.mark.parametrize("mode", sorted(CASES))
def test_replayed_or_mismatched_answer_ends_episode(
    mode: str, signing_hostile: HostileServer, small_spec: EpisodeSpec
) -> None:
    policy = RemotePolicy(f"{signing_hostile.url}/{mode}", SECRET, step_timeout_s=2)
    result = run_episode(small_spec, policy, "math")
    assert result.termination == "protocol_violation", result.termination_detail
    assert CASES[mode] in result.termination_detail
    # The replay is caught at the first step whose answer is not its own (step 1); the others at step 0.
    assert result.boxes_placed == (1 if mode == "replay" else 0)


def test_replayed_answer_would_pass_unchecked(
    signing_hostile: HostileServer, small_spec: EpisodeSpec
) -> None:
    """Control: without the answer check the very same replay is played (four boxes stacked on one spot),
    so the test above fails if the check is missing."""
    result = run_episode(small_spec, RemotePolicy(f"{signing_hostile.url}/replay", step_timeout_s=2), "math")
    assert result.termination == "completed", result.termination_detail
    assert result.boxes_placed == len(small_spec.boxes)


def test_info_without_protocol_is_refused(signing_hostile: HostileServer) -> None:
    from robobpp.policies.base import PolicyError

    policy = RemotePolicy(f"{signing_hostile.url}/empty_info", SECRET)
    with pytest.raises(PolicyError) as err:
        policy.fetch_info()
    assert err.value.reason == "protocol_violation"
    assert "missing field 'protocol'" in err.value.detail
