"""A full computation works through a board a block of resamples and a tile of entries at a time
(``BoardMatrix._renormalise``): however the board is cut, its figures are the same bits, and the same as the
from-scratch reference's; the grids sum what the boards handed over on their way (``GridSums``), the same bits
as computing it again."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from robobpp.boards import matrix
from robobpp.boards.engine import BoardEngine, _Gathering, compute_snapshot
from robobpp.boards.grid import GridMatrix, GridSums, stable_interval
from robobpp.boards.records import Published
from tests.server.test_bench_seed import _seed, runtime_for
from tests.server.test_board_engine import same


def test_tiles_and_blocks_give_the_same_bits(
    db_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    runtime = runtime_for(db_url, tmp_path)
    try:
        # 24 submissions: pooled metrics, the paper protocol's boards, one failed and one partial entry
        _seed.seed(runtime, 24, episodes_every=24, newest=1, progress=False)

        def start() -> dict[Any, Published]:
            return BoardEngine(runtime.read_session, _seed.DATASETS, _seed.SETTINGS).update("private")

        whole = start()  # every board one block of 1,000 resamples and one tile of its entries
        monkeypatch.setattr(matrix, "BLOCK_VALUES", 1)  # blocks of 64 resamples: 15 of them and one of 40
        monkeypatch.setattr(matrix, "TILE_VALUES", 1)  # tiles of 16 entries: a full one and a shorter one
        cut = start()
        same(cut, whole)  # bit for bit
        with runtime.read_session() as s:
            scratch = dict(compute_snapshot(s, _seed.DATASETS, _seed.SETTINGS, "private"))
        same(cut, scratch, tol=1e-12)
    finally:
        runtime.dispose()


def test_a_workspace_shared_by_every_board_leaves_no_trace(
    db_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A full computation makes its large arrays in one workspace, board after board (``matrix.Workspace``):
    each array is written whole before it is read, so memory poisoned before every use, or fresh memory
    every time, gives the same bits; and the memory is reused (boards of different sizes share it)."""
    runtime = runtime_for(db_url, tmp_path)
    try:
        _seed.seed(runtime, 12, episodes_every=12, newest=1, progress=False)

        def start() -> dict[Any, Published]:
            return BoardEngine(runtime.read_session, _seed.DATASETS, _seed.SETTINGS).update("private")

        made: list[int] = []
        handed: list[np.ndarray] = []
        reused = matrix.Workspace.array

        def poisoned(
            self: matrix.Workspace, name: str, shape: tuple[int, ...], dtype: Any = np.float64
        ) -> Any:
            out = reused(self, name, shape, dtype)
            made.append(0 if any(np.shares_memory(out, h) for h in handed) else 1)
            handed.append(out)
            out[...] = -7 if np.dtype(dtype).kind == "i" else np.nan
            return out

        monkeypatch.setattr(matrix.Workspace, "array", poisoned)
        dirty = start()
        assert 0 < sum(made) < len(made)  # fresh memory for some, reused for the others
        monkeypatch.setattr(
            matrix.Workspace, "array", lambda self, name, shape, dtype=np.float64: np.empty(shape, dtype)
        )
        same(dirty, start())  # bit for bit
    finally:
        runtime.dispose()


def test_grid_sums_gathered_on_the_way_equal_the_grids_own(
    db_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A full computation's grids sum the samples each board handed over on its way; without them a grid
    computes every board's samples of its rows again: the same bits."""
    runtime = runtime_for(db_url, tmp_path)
    try:
        _seed.seed(runtime, 12, episodes_every=12, newest=1, progress=False)

        def start() -> dict[Any, Published]:
            return BoardEngine(runtime.read_session, _seed.DATASETS, _seed.SETTINGS).update("private")

        gathered = start()
        calls: list[int] = []
        own = GridMatrix._samples

        def counted(self: GridMatrix, *args: Any) -> Any:
            calls.append(1)
            return own(self, *args)

        monkeypatch.setattr(GridMatrix, "_samples", counted)
        assert start().keys() == gathered.keys()
        assert not calls  # the gathered sums served every row
        monkeypatch.setattr(BoardEngine, "_gathering", lambda self, state: _Gathering({}, {}))
        computed = start()
        assert len(calls) == 2  # each grid (closed loop, paper protocol) computed its rows' sums
        same(gathered, computed)  # bit for bit
    finally:
        runtime.dispose()


def test_grid_sums_follow_the_grids_order_and_rows() -> None:
    keys = ["math/a", "math/b"]
    rel = np.arange(12, dtype=np.float32).reshape(3, 4)
    stable = rel / 2
    sums = GridSums(keys)
    sums.add("math/a", np.array([1, 2, 3]), rel, stable)
    assert sums.rows(np.array([1, 2, 3])) is None  # not every board added yet
    sums.add("math/b", np.array([2, 3, 9]), rel, stable)  # submission 1 is not on board b: no row
    found = sums.rows(np.array([2, 3]))
    assert found is not None
    assert found[0].tolist() == [(rel[1] + rel[0]).tolist(), (rel[2] + rel[1]).tolist()]
    stable_sums = np.array([stable[1] + stable[0], stable[2] + stable[1]], dtype=np.float64)
    assert found[1].tolist() == stable_interval(stable_sums, 2).tolist()
    assert found[1].shape == (2, 2)
    assert sums.rows(np.array([3])) is not None
    assert sums.rows(np.array([1, 2])) is None  # a row it does not have: the grid computes its own
    other = GridSums(keys)
    other.add("math/b", np.array([1]), rel[:1], stable[:1])  # out of the grid's order: turned off
    other.add("math/a", np.array([1]), rel[:1], stable[:1])
    assert other.rows(np.array([1])) is None


def test_grid_sums_of_boards_with_the_same_rows_add_them_as_they_come() -> None:
    """Every row on every board (the usual case): each board's samples are added whole, no gather."""
    rel = np.arange(12, dtype=np.float32).reshape(3, 4) / 7
    sums = GridSums(["math/a", "math/b"])
    sums.add("math/a", np.array([4, 5, 6]), rel, rel)
    sums.add("math/b", np.array([4, 5, 6]), rel[::-1].copy(), rel)
    found = sums.rows(np.array([4, 5, 6]))
    assert found is not None
    expected = rel.astype(np.float64) + rel[::-1].astype(np.float64)
    assert found[0].tobytes() == expected.tobytes()
