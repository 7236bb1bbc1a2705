"""Shared fixtures: hand-built episode specs (no data needed), the real-data cache (network on first use) and
fresh databases (``db_url``: a SQLite file, or a new PostgreSQL database per test).

Set ``ROBOBPP_TEST_DATA_DIR`` to reuse one verified cache across runs; otherwise the wheel is downloaded and
converted once per test session into a temporary cache.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pytest

from robobpp.core import Box, ContainerSpec, EpisodeSpec
from robobpp.datasets.importer import fetch

# The board worker runs as a thread of the server under test (boards/worker.py): a spawned process per
# app would cost each test a second's start-up; tests/server/test_board_publishing.py runs the process mode.
os.environ.setdefault("ROBOBPP_BOARD_WORKER", "thread")

PG_ADMIN_URL = os.environ.get("ROBOBPP_TEST_PG", "postgresql://postgres@127.0.0.1:5432/test")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Tests marked ``slow`` first, the rest in path order. Under xdist's ``worksteal`` (the README's command)
    each long test (a physics fidelity run takes 4–6 minutes on a 2-core machine) then starts at once, and the
    workers share the many short ones around it, where in path order a long one could start near the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)  # a stable sort


def _floats(dims: tuple[float, float, float]) -> tuple[float, float, float]:
    length, width, height = dims
    return float(length), float(width), float(height)


def make_spec(
    boxes: Sequence[tuple[float, float, float]] | Sequence[Box],
    container: tuple[float, float, float] = (10, 10, 10),
    threshold: float = 7.0,
    dataset: str = "handmade",
    group: int = 0,
) -> EpisodeSpec:
    """An episode over the given boxes (tuples are (l, w, h) with 1 kg mass)."""
    items = tuple(b if isinstance(b, Box) else Box(*_floats(b), 1.0) for b in boxes)
    return EpisodeSpec(dataset, "train", group, items, ContainerSpec(*container), threshold, 0)


@pytest.fixture
def random_spec() -> EpisodeSpec:
    """80 random boxes in the Repetitive container (deterministic)."""
    rng = np.random.default_rng(7)
    dims = rng.integers(15, 55, size=(80, 3))
    return make_spec(
        [(float(a), float(b), float(c)) for a, b, c in dims], container=(134, 125, 100), dataset="synthetic"
    )


@pytest.fixture(scope="session")
def real_data_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A verified, converted data cache (network on first use: pip download of packsim==0.0.4)."""
    shared = os.environ.get("ROBOBPP_TEST_DATA_DIR")
    root = Path(shared) if shared else tmp_path_factory.mktemp("robobpp-data")
    fetch(root)
    return root


@pytest.fixture
def real_data(real_data_root: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Point the library at the session cache for one test."""
    monkeypatch.setenv("ROBOBPP_DATA_DIR", str(real_data_root))
    return real_data_root


def _pg_available() -> bool:
    try:
        import psycopg

        with psycopg.connect(PG_ADMIN_URL, connect_timeout=3):
            return True
    except Exception:  # noqa: BLE001
        return False


@pytest.fixture
def pg_url() -> Iterator[str]:
    """A brand-new PostgreSQL database, dropped afterwards (tests never see each other's rows)."""
    import psycopg

    if not _pg_available():
        pytest.skip("PostgreSQL is not reachable at 127.0.0.1:5432")
    name = f"robobpp_t_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    base = PG_ADMIN_URL.rsplit("/", 1)[0].replace("postgresql://", "postgresql+psycopg://")
    yield f"{base}/{name}"
    with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def db_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'robobpp.sqlite3'}"
    return request.getfixturevalue("pg_url")
