"""Real-data fixtures: the packsim wheel is downloaded and converted once per test session.

Set ``ROBOBPP_TEST_DATA_DIR`` to reuse one cache across runs (it is verified, not trusted); otherwise a
temporary cache is used and removed with the session.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from robobpp.datasets.cache import converted_dir, wheels_dir
from robobpp.datasets.importer import fetch
from robobpp.datasets.sources import WHEEL_NAME


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


@pytest.fixture
def real_wheel(real_data_root: Path) -> Path:
    return wheels_dir(real_data_root) / WHEEL_NAME


@pytest.fixture
def cache_copy(real_data_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A private copy of the converted cache (and wheel) that a test may damage."""
    root = tmp_path / "data"
    shutil.copytree(converted_dir(real_data_root), converted_dir(root))
    shutil.copytree(wheels_dir(real_data_root), wheels_dir(root))
    monkeypatch.setenv("ROBOBPP_DATA_DIR", str(root))
    return root
