"""What the JSON API serves is what it declares: every GET operation under ``/api/v1`` in the OpenAPI
document is called on a real app holding finished, failed, partial and queued submissions, and each body is
validated against the operation's published response schema, made strict: every served key declared, every
value of the declared JSON type.

Several routes serve pre-built JSON bytes (the boards, the grid, the reproduction table, the submission
lists and episodes) that FastAPI never checks against their ``response_model``. The OpenAPI document is the
contract that generated clients and ``ServerClient`` rely on, so a field served but undeclared, or declared
with another type, fails here. The test reads only HTTP answers, so it holds however the bodies are built.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from jsonschema import Draft202012Validator

from robobpp.server.app import create_app
from robobpp.server.bootstrap import bootstrap
from robobpp.server.config import Settings
from robobpp.worker.options import worker_options
from robobpp.worker.run import claim_and_run
from tests.server.conftest import submit_direct
from tests.server.test_board import NaNPolicy

ADMIN_TOKEN = "schema-admin-token-0123456789abcdef"
ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
GROUPS = 2


def strict(schema: Any) -> Any:
    """The schema with every object closed (``additionalProperties: false`` where it names its properties
    and says nothing of others): pydantic leaves objects open, so undeclared keys would pass unseen."""
    if isinstance(schema, list):
        return [strict(s) for s in schema]
    if not isinstance(schema, dict):
        return schema
    closed = {key: strict(value) for key, value in schema.items()}
    if "properties" in closed and "additionalProperties" not in closed:
        closed["additionalProperties"] = False
    return closed


def response_validators(openapi: dict[str, Any]) -> dict[str, Draft202012Validator]:
    """Path → a validator of its GET answer (200, JSON), for every such operation under /api/v1."""
    components = strict(openapi["components"])
    validators = {}
    for path, item in openapi["paths"].items():
        content = item.get("get", {}).get("responses", {}).get("200", {}).get("content", {})
        schema = content.get("application/json", {}).get("schema")
        if path.startswith("/api/v1") and schema:
            validators[path] = Draft202012Validator({**strict(schema), "components": components})
    return validators


def problems(validator: Draft202012Validator, body: bytes) -> list[str]:
    return [
        f"{'/'.join(map(str, e.absolute_path)) or '(body)'}: {e.message}"
        for e in validator.iter_errors(json.loads(body))
    ]


@pytest.fixture
def served(tmp_path: Path, policy_server):
    """An app with boards to serve: two complete entries, a partial one, a failed one (a policy answering
    NaN), the baselines on the public track, and a submission still queued."""
    settings = Settings(
        database_url=f"sqlite:///{tmp_path / 'schemas.sqlite3'}",
        state_dir=tmp_path,
        admin_token=ADMIN_TOKEN,
        workers=0,
        evaluate_baselines=True,
        baselines=("dbl",),
        settings=("math",),
        datasets=("diverse", "longboard"),
        groups=GROUPS,
        allow_private_policy_urls=True,
        board_refresh_s=0,
        spec_provider="robobpp.worker.specs:offline_spec",
    )
    app = create_app(settings, start_workers=False)
    bootstrap(app.state.runtime)
    both = ("diverse", "longboard")
    ids = {
        "done": submit_direct(app, "alice", "builtin:dbl", datasets=both, groups=GROUPS),
        "random": submit_direct(app, "bob", "builtin:random", datasets=both, groups=GROUPS),
        "partial": submit_direct(app, "carol", "builtin:hm", datasets=("diverse",), groups=GROUPS),
        # the boards of lookahead 10 are served beside the leaderboard's (lookahead 0)
        "lookahead": submit_direct(app, "olga", "builtin:dbl", datasets=both, groups=GROUPS, lookahead=10),
        "failed": submit_direct(
            app, "mallory", policy_server(NaNPolicy, secret=None).url, datasets=both, groups=GROUPS
        ),
    }
    runtime = app.state.runtime
    while claim_and_run(runtime.session_factory, worker_options(runtime.settings), "test:host:1") is not None:
        pass
    ids["queued"] = submit_direct(app, "dave", "builtin:dbl", datasets=("diverse",), groups=GROUPS)
    with TestClient(app) as client:
        yield client, ids
    runtime.dispose()


def test_every_json_route_serves_its_declared_schema(served) -> None:
    client, ids = served
    validators = response_validators(client.get("/openapi.json").json())
    board_queries: list[dict[str, Any]] = [
        {"view": view, "track": track} for view in ("best", "all") for track in ("private", "public")
    ]
    board_queries += [{"view": "all", "limit": 1, "offset": 1}, {"protocol": "paper"}, {"lookahead": 10}]
    checked = []
    for path, validator in validators.items():
        queries = board_queries if path.startswith("/api/v1/leaderboards") else [{}]
        for name in ("done", "failed", "partial", "queued", "lookahead"):
            episodes = client.get(f"/api/v1/submissions/{ids[name]}/episodes", headers=ADMIN).json()
            url = path.format(
                dataset="diverse", setting="math", submission_id=ids[name], episode_id=episodes[0]["id"]
            )
            for params in queries:
                response = client.get(url, params=params, headers=ADMIN)
                assert response.status_code == 200, (url, params, response.text)
                assert response.headers["content-type"] == "application/json"
                assert not problems(validator, response.content), (
                    url,
                    params,
                    problems(validator, response.content),
                )
                checked.append((path, response.content))
    # a participant's own view: /me with its quota, its (empty) list, a baseline's episodes as others see them
    token = client.post("/api/v1/participants", json={"name": "erin"}, headers=ADMIN).json()["token"]
    erin = {"Authorization": f"Bearer {token}"}
    me = client.get("/api/v1/me", headers=erin)
    assert me.json()["quota"] and not problems(validators["/api/v1/me"], me.content)
    mine = client.get("/api/v1/submissions", headers=erin)
    assert not problems(validators["/api/v1/submissions"], mine.content)
    public = client.get("/api/v1/leaderboards/diverse/math", params={"track": "public"}).json()["entries"]
    baseline = public[0]["submission_id"]
    seen = client.get(f"/api/v1/submissions/{baseline}/episodes", headers=erin)
    assert seen.status_code == 200 and not problems(
        validators["/api/v1/submissions/{submission_id}/episodes"], seen.content
    )
    paths = {path for path, _ in checked}
    assert paths == set(validators) and len(paths) >= 10, paths
    # the boards were not empty: ranked entries, apart ones, and both tracks were validated
    board = json.loads(
        client.get("/api/v1/leaderboards/diverse/math", params={"view": "all"}, headers=ADMIN).content
    )
    assert len(board["entries"]) >= 2 and board["unranked"]


def test_the_check_sees_an_undeclared_field_and_a_wrong_type(served) -> None:
    client, _ids = served
    validators = response_validators(client.get("/openapi.json").json())
    validator = validators["/api/v1/leaderboards/{dataset}/{setting}"]
    body = client.get("/api/v1/leaderboards/diverse/math", params={"view": "all"}).json()
    assert not problems(validator, json.dumps(body).encode())
    body["entries"][0]["surprise"] = 1
    body["groups"] = "two"
    found = problems(validator, json.dumps(body).encode())
    assert any(p.startswith("entries/0") and "surprise" in p for p in found), found
    assert any(p.startswith("groups") for p in found), found
