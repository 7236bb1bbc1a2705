"""Real-data fixtures: the packsim wheel is downloaded and converted once per test session.

Set ``ROBOBPP_TEST_DATA_DIR`` to reuse one cache across runs (it is verified, not trusted); otherwise a
temporary cache is used and removed with the session.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from robobpp.datasets.cache import converted_dir, wheels_dir
from robobpp.datasets.sources import WHEEL_NAME


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
