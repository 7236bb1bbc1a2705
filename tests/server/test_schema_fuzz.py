"""Property-based requests generated from the OpenAPI schema (schemathesis): never a 5xx.

Bounded (a few dozen examples per operation) so it stays well under two minutes.
"""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, settings

from robobpp.server.app import create_app
from robobpp.server.bootstrap import bootstrap
from tests.server.conftest import ADMIN_TOKEN
from tests.server.test_api import make_settings


@pytest.fixture
def fuzz_schema(tmp_path_factory):  # type: ignore[no-untyped-def]
    tmp = tmp_path_factory.mktemp("fuzz")
    app = create_app(make_settings(f"sqlite:///{tmp / 'fuzz.sqlite3'}", tmp, evaluate_baselines=True,
                                   allow_private_policy_urls=False))  # fmt: skip
    bootstrap(app.state.runtime)  # migrations + baseline rows, so reads have something to find
    return schemathesis.openapi.from_asgi("/openapi.json", app)


schema = schemathesis.pytest.from_fixture("fuzz_schema")


@schema.parametrize()
@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
def test_no_server_errors(case) -> None:  # type: ignore[no-untyped-def]
    for headers in ({"Authorization": f"Bearer {ADMIN_TOKEN}"}, {}):
        response = case.call(headers=headers)
        assert response.status_code < 500, (
            case.method,
            case.formatted_path,
            response.status_code,
            response.text,
        )
