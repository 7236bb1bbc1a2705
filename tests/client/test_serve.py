"""The SDK policy server: same observation as in-process, signatures enforced, clear errors."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator

import httpx
import numpy as np
import pytest

from robobpp import protocol as P
from robobpp.client.remote import RemotePolicy
from robobpp.client.serve import BackgroundServer, create_policy_app
from robobpp.core import Action, ContainerSpec, EpisodeInfo, EpisodeSpec, Observation
from robobpp.episode import Episode, run_episode
from robobpp.policies.base import BasePolicy
from robobpp.policies.dbl import DBL

SECRET = "correct horse battery staple"


class Recorder(BasePolicy):
    """Answers DBL and keeps what it was given, so a test can compare it with the in-process view."""

    name = "recorder"

    def __init__(self) -> None:
        self.dbl = DBL()
        self.seen: list[Observation] = []
        self.resets: list[EpisodeInfo] = []
        self.closes: list[str] = []

    def reset(self, info: EpisodeInfo) -> None:
        self.resets.append(info)

    def act(self, obs: Observation) -> Action | None:
        self.seen.append(obs)
        return self.dbl.act(obs)

    def close(self, reason: str) -> None:
        self.closes.append(reason)


class Broken(BasePolicy):
    name = "broken"

    def act(self, obs: Observation) -> Action | None:
        if obs.step == 0:
            return Action(float("nan"), 0.0, 0)
        raise ZeroDivisionError("division by zero in my heuristic")


@pytest.fixture(scope="module")
def signed() -> Iterator[BackgroundServer]:
    with BackgroundServer(create_policy_app(DBL(), SECRET)) as server:
        yield server


def _body(payload: object) -> bytes:
    return json.dumps(payload).encode()


def test_remote_dbl_matches_in_process_dbl_exactly(random_spec: EpisodeSpec) -> None:
    recorder = Recorder()
    with BackgroundServer(create_policy_app(recorder, SECRET)) as server:
        remote = run_episode(random_spec, RemotePolicy(server.url, SECRET), "math", lookahead=2)
    local = run_episode(random_spec, DBL(), "math", lookahead=2)
    assert remote.termination == local.termination
    assert remote.boxes_placed == local.boxes_placed > 10
    assert remote.final == local.final
    assert [(s.action, s.placement) for s in remote.steps] == [(s.action, s.placement) for s in local.steps]
    drop = {"decision_time", "round_trip", "network_estimate"}  # wall-clock figures
    assert {k: v for k, v in remote.metrics.items() if k not in drop} == {
        k: v for k, v in local.metrics.items() if k not in drop
    }
    # The policy saw the in-process observation: same placements, same heightmap, same lookahead.
    assert recorder.resets[0].container == random_spec.container and recorder.resets[0].lookahead == 2
    assert recorder.closes == [local.termination]
    replay = Episode(random_spec, "math", lookahead=2)
    for obs, step in zip(recorder.seen, local.steps, strict=True):
        expected = replay.observe()
        assert (
            obs.placed == expected.placed and obs.box == expected.box and obs.lookahead == expected.lookahead
        )
        np.testing.assert_array_equal(obs.heightmap, expected.heightmap)
        assert not obs.heightmap.flags.writeable
        if step.action is None:  # the last answer: no feasible placement
            break
        replay.step(Action(step.action["x"], step.action["y"], int(step.action["orientation"])), 0.0)
    # The self-reported compute time comes back beside the measured decision time.
    placed = [s for s in remote.steps if s.action is not None]
    assert all(s.compute_time is not None and 0 <= s.compute_time < s.decision_time for s in placed)


def test_wire_round_trip_keeps_odd_floats_and_tilted_boxes() -> None:
    from robobpp.core import Box, Placement

    container = ContainerSpec(120.5, 99.25, 170)
    placed = (
        Placement(0.1, 0.2, 0.0, 10.333333333333334, 20.1, 5.7, 0, 0),
        Placement(3.0000000000000004, 7.5, 5.7, 12.0, 9.0, 3.0, 1, 1, (0.01, -0.02, 0.0, 0.9997499)),
    )
    from robobpp.sim.physics.config import PhysicsConfig
    from robobpp.sim.physics.geometry import heightmap_from_boxes

    # a tilted box is a physical state: its heightmap is the physical settings' (actual bounds, shrunk, rounded)
    halves = np.array([(p.length, p.width, p.height) for p in placed]) / 2
    centers = np.array([(p.x, p.y, p.z) for p in placed]) + halves
    quats = np.array([p.quaternion or (0, 0, 0, 1) for p in placed])
    config = PhysicsConfig()
    bounds = heightmap_from_boxes(container.grid_shape, centers, quats, halves, config.heightmap_shrink_cm)
    heightmap = np.round(bounds / config.heightmap_resolution_cm) * config.heightmap_resolution_cm
    obs = Observation("e-1", 2, container, placed, heightmap, Box(1.5, 2.5, 3.5, 0.7), (Box(4, 5, 6, 1),))
    wire = P.ActRequest.model_validate_json(json.dumps(P.act_payload(obs)))
    back = P.observation_from_act(wire)
    assert back.placed == obs.placed and back.box == obs.box and back.lookahead == obs.lookahead
    np.testing.assert_array_equal(back.heightmap, obs.heightmap)
    assert back.heightmap.max() > 5.7 + 3.0  # the tilted box's top corner stands above its nominal top


def test_a_served_observation_does_not_change_when_the_next_one_is_rebuilt_from_it(small_spec) -> None:
    """The receiver rebuilds each heightmap from the previous observation's (Math Pack: incrementally); the
    previous one, which the policy may keep, stays as it was, and neither can be written."""
    episode = Episode(small_spec, "math")
    first = P.observation_from_act(
        P.ActRequest.model_validate_json(json.dumps(P.act_payload(episode.observe())))
    )
    before = first.heightmap.copy()
    episode.step(Action(0, 0, 0), 0.0)
    wire = P.ActRequest.model_validate_json(json.dumps(P.act_payload(episode.observe())))
    second = P.observation_from_act(wire, previous=first)
    assert second.heightmap.max() > 0 and not np.shares_memory(first.heightmap, second.heightmap)
    np.testing.assert_array_equal(first.heightmap, before)
    assert not first.heightmap.flags.writeable and not second.heightmap.flags.writeable


# The headers are made when the test runs, not at collection: a suite that reaches this test more than the 300 s
# window after collecting it would otherwise see every timestamp as stale.
@pytest.mark.parametrize(
    ("make_headers", "words"),
    [
        (lambda: {}, "missing"),
        (lambda: {P.TIMESTAMP_HEADER: str(int(time.time())), P.SIGNATURE_HEADER: "0" * 64}, "does not match"),
        (lambda: P.signed_headers("wrong secret", b"{}"), "does not match"),
        (lambda: P.signed_headers(SECRET, b"{}", now=time.time() - 3600), "stale"),
        (lambda: P.signed_headers(SECRET, b"{}", now=time.time() + 3600), "stale"),
        (lambda: {P.TIMESTAMP_HEADER: "12.5", P.SIGNATURE_HEADER: "00"}, "whole seconds"),
        (lambda: P.signed_headers(SECRET, b'{"episode_id": "x"}'), "does not match"),  # signed another body
    ],
)
def test_bad_or_stale_signature_is_refused_with_401(
    signed: BackgroundServer, make_headers: Callable[[], dict[str, str]], words: str
) -> None:
    headers = make_headers()
    body = b"{}"
    for method, path in (("GET", "/info"), ("POST", "/reset"), ("POST", "/act"), ("POST", "/close")):
        response = httpx.request(method, signed.url + path, content=body, headers=headers)
        assert response.status_code == 401, (path, response.text)
        assert response.json()["error"] == "unauthorized"
        assert words in response.json()["detail"]


def test_valid_signature_is_accepted(signed: BackgroundServer) -> None:
    response = httpx.get(signed.url + "/info", headers=P.signed_headers(SECRET, b""))
    assert response.status_code == 200
    assert P.InfoResponse.model_validate_json(response.content).protocol == "robobpp/1"


def test_remote_policy_with_wrong_secret_ends_with_clear_reason(signed: BackgroundServer, small_spec) -> None:
    result = run_episode(small_spec, RemotePolicy(signed.url, "not the secret"), "math")
    assert result.termination == "policy_error"
    assert "HTTP 401" in result.termination_detail and "secret" in result.termination_detail


def test_malformed_requests_get_422_in_plain_words(signed: BackgroundServer) -> None:
    def post(path: str, payload: object) -> httpx.Response:
        body = _body(payload)
        return httpx.post(signed.url + path, content=body, headers=P.signed_headers(SECRET, body))

    bad_box = {
        "episode_id": "e",
        "step": 0,
        "placed": [],
        "box": {"length": -1, "width": 1, "height": 1, "mass": 1},
        "container": {"length": 10, "width": 10, "height": 10},
        "colour": "red",
    }
    response = post("/act", bad_box)
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert (
        "field 'box.length': input should be greater than 0" in detail and "unknown field 'colour'" in detail
    )
    # No container in /act and no /reset for this episode: the SDK cannot build a heightmap.
    orphan = {
        "episode_id": "never-reset",
        "step": 0,
        "placed": [],
        "box": {"length": 1, "width": 1, "height": 1, "mass": 1},
    }
    response = post("/act", orphan)
    assert response.status_code == 422 and "send /reset first" in response.json()["detail"]


def test_a_policy_that_raises_or_answers_nan_gets_500_and_a_recorded_reason(small_spec) -> None:
    with BackgroundServer(create_policy_app(Broken())) as server:
        first = run_episode(small_spec, RemotePolicy(server.url), "math")
    assert first.termination == "policy_error"
    assert "HTTP 500" in first.termination_detail and "not finite" in first.termination_detail


def test_a_policy_that_raises_reports_its_exception(small_spec) -> None:
    class RaisesAtOnce(BasePolicy):
        def act(self, obs: Observation) -> Action | None:
            raise ZeroDivisionError("division by zero in my heuristic")

    with BackgroundServer(create_policy_app(RaisesAtOnce)) as server:
        result = run_episode(small_spec, RemotePolicy(server.url), "math")
    assert result.termination == "policy_error"
    assert "act raised ZeroDivisionError: division by zero in my heuristic" in result.termination_detail


def test_openapi_and_json_schema_come_from_the_protocol_models(signed: BackgroundServer) -> None:
    import jsonschema

    doc = httpx.get(signed.url + "/openapi.json").json()
    assert {"ActRequest", "ActResponse", "ResetRequest", "PlacedModel"} <= set(doc["components"]["schemas"])
    act_body = doc["paths"]["/act"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    assert act_body == {"$ref": "#/components/schemas/ActRequest"}
    schema = P.json_schema()
    response_schema = {**schema, "$ref": "#/$defs/ActResponse"}
    jsonschema.validate({"x": 1.5, "y": 0, "orientation": 1, "compute_time": 0.01}, response_schema)
    jsonschema.validate({"x": None, "y": None, "orientation": None}, response_schema)
    for bad in (
        {"x": 1, "y": 0, "orientation": 0, "z": 1},
        {"x": 1, "y": 0},
        {"x": 1e9, "y": 0, "orientation": 0},
    ):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, response_schema)


def test_sdk_serve_is_the_function_even_after_its_module_was_imported() -> None:
    """``from robobpp.client import serve`` (docs, examples) must give the function, not the submodule."""
    import inspect
    import subprocess
    import sys

    from robobpp.client import serve
    from robobpp.client.serve import serve as serve_function

    assert serve is serve_function  # this file imported robobpp.client.serve (the module) first
    fresh = "from robobpp.client import serve; import robobpp.client.serve; print(callable(serve))"
    out = subprocess.run([sys.executable, "-c", fresh], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True"
    assert inspect.isfunction(serve)


class Versioned(BasePolicy):
    name = "versioned"
    version = "1.2"

    def act(self, obs: Observation) -> Action | None:
        return None


@pytest.mark.parametrize(("policy", "expected"), [(DBL(), "dbl"), (Versioned(), "versioned 1.2")])
def test_results_are_labelled_by_info_name_and_only_a_reported_version(
    policy: BasePolicy, expected: str
) -> None:
    # DBL reports no version: /info carries the protocol's default, which labels leave out ("dbl", not "dbl 0")
    with BackgroundServer(create_policy_app(policy)) as server:
        remote = RemotePolicy(server.url)
        info = remote.fetch_info()
        remote.close()
    assert (info.name, info.version) == (expected.split()[0], getattr(policy, "version", None) or "0")
    assert remote.name == expected
