"""Fixtures of the client tests: one hostile server per module, a small episode."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from robobpp.core import EpisodeSpec
from tests.client.hostile import HostileServer
from tests.conftest import make_spec


@pytest.fixture(scope="module")
def hostile() -> Iterator[HostileServer]:
    with HostileServer(slow_s=3.0) as server:
        yield server


@pytest.fixture
def small_spec() -> EpisodeSpec:
    """Four boxes in a 20 × 20 × 20 cm container (all fit, so only the policy can end it early)."""
    return make_spec([(10, 10, 5), (10, 10, 5), (10, 10, 5), (10, 10, 5)], container=(20, 20, 20))
