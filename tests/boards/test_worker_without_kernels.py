"""A board worker on an install without the compiled kernels says so as it starts (and computes with numpy)."""

from __future__ import annotations

import logging
from typing import Any, cast

import pytest

from robobpp.boards.worker import BoardWorker
from robobpp.scoring import kernels


@pytest.mark.parametrize("built", [True, False])
def test_the_board_worker_warns_when_the_kernels_are_not_built(
    built: bool, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(kernels, "BUILT", built)  # the worker reads it from the module as it starts
    with caplog.at_level(logging.WARNING, logger="robobpp.server"):
        BoardWorker(cast(Any, None)).run(alive=lambda: False)  # starts, and stops before its first pass
    warned = [r.getMessage() for r in caplog.records if "_kernels is not built" in r.getMessage()]
    assert len(warned) == (0 if built else 1)
