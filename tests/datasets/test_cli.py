"""``robobpp datasets`` end to end: fetch, info, build-private and their errors."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from robobpp.cli.datasets import app
from robobpp.datasets import load_private
from robobpp.datasets.sources import WHEEL_NAME

runner = CliRunner()


@pytest.fixture(autouse=True)
def _restore_data_dir(monkeypatch: pytest.MonkeyPatch) -> None:
    """`--data-dir` sets ROBOBPP_DATA_DIR in this process (CliRunner runs in-process): undo it after each test."""
    monkeypatch.setenv("ROBOBPP_DATA_DIR", os.environ.get("ROBOBPP_DATA_DIR", ""))
    if not os.environ["ROBOBPP_DATA_DIR"]:
        monkeypatch.delenv("ROBOBPP_DATA_DIR")


def test_unknown_dataset_is_a_clear_error() -> None:
    result = runner.invoke(app, ["info", "--dataset", "nope"])
    assert result.exit_code != 0
    assert "unknown dataset nope" in result.output


def test_negative_seed_is_refused(tmp_path: Path) -> None:
    result = runner.invoke(app, ["build-private", "--root", str(tmp_path), "--seed", "-3"])
    assert result.exit_code != 0


def test_fetch_of_a_missing_wheel_file(tmp_path: Path) -> None:
    result = runner.invoke(app, ["fetch", "--data-dir", str(tmp_path), "--wheel", str(tmp_path / "x.whl")])
    assert result.exit_code == 1
    assert "x.whl" in result.output and "not found" in result.output


@pytest.mark.network
def test_fetch_prints_the_counts(real_data_root: Path) -> None:
    result = runner.invoke(app, ["fetch", "--data-dir", str(real_data_root)])
    assert result.exit_code == 0, result.output
    for text in ("16,767", "6,849", "6,801", "293", "58 duplicate", "48 zero-size", "9 unplaceable"):
        assert text in result.output


@pytest.mark.network
def test_fetch_refuses_an_altered_wheel(real_wheel: Path, tmp_path: Path) -> None:
    altered = tmp_path / WHEEL_NAME
    altered.write_bytes(real_wheel.read_bytes() + b"\0")
    result = runner.invoke(app, ["fetch", "--data-dir", str(tmp_path / "c"), "--wheel", str(altered)])
    assert result.exit_code == 1
    assert WHEEL_NAME in result.output and "sha256 mismatch" in result.output
    assert not (tmp_path / "c" / "packsim-0.0.4").exists()


@pytest.mark.network
def test_info_table(real_data: Path) -> None:
    result = runner.invoke(app, ["info"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    row = next(line for line in lines if "repetitive" in line and "test" in line)
    assert "3,353" in row and "6,212" in row  # records and boxes (quantities expanded)
    assert any("diverse" in line and "1,388" in line for line in lines)
    board = [line for line in lines if "longboard" in line]
    assert any("234" in line and "227" in line and "unplaceable, excluded: 7" in line for line in board)
    assert any("59" in line and "57" in line and "unplaceable, excluded: 2" in line for line in board)


@pytest.mark.network
def test_build_private_through_the_entry_point(real_data_root: Path, tmp_path: Path) -> None:
    root = tmp_path / "datasets_private"
    env = {**os.environ, "ROBOBPP_DATA_DIR": str(real_data_root)}
    cmd = [
        sys.executable,
        "-c",
        "from robobpp.cli import main; main()",
        "datasets",
        "build-private",
        "--root",
        str(root),
        "--groups",
        "3",
        "--seed",
        "99",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    assert "longboard: 3 groups" in proc.stderr
    assert len(load_private("repetitive", root)) == 3
    bad = subprocess.run(
        [*cmd[:5], "--root", str(root / "diverse.json")],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        check=False,
    )
    assert bad.returncode == 1 and "not a directory" in bad.stderr
