"""The paper's published figures as package data: complete, each with its source table, loaded from the wheel."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from robobpp.paper import PAPER_BASELINES, paper_tables
from robobpp.scoring import kernels
from robobpp.scoring.metrics import metrics_for

DATASETS = ("repetitive", "diverse", "longboard")


def test_every_metric_of_every_method_is_there_with_its_table() -> None:
    t = paper_tables()
    assert len(t.methods) == 12 and set(PAPER_BASELINES) <= set(t.methods)
    for setting in ("math", "physics", "execution"):
        expected = (
            [m.key for m in metrics_for(setting)] + (["pph"] if setting == "execution" else []) + ["score"]
        )
        assert list(t.metrics(setting)) == expected  # utilisation first, in the paper's order
        for dataset in DATASETS:
            for method in t.methods:
                for metric in expected:
                    v = t.get(setting, dataset, method, metric)
                    assert v is not None, (setting, dataset, method, metric)
                    assert v.table in t.tables and t.tables[v.table], v
    assert len(t.values) == len({(v.setting, v.dataset, v.method, v.metric) for v in t.values}) == 720


@pytest.mark.parametrize(
    ("key", "value", "table"),
    [
        (("math", "repetitive", "dbl", "space_utilization"), 0.617, "tab:pg setting12"),
        (("physics", "diverse", "hm", "space_utilization"), 0.330, "tab:deli setting12"),
        (("physics", "longboard", "pct", "static_stability"), 0.371, "tab:opai setting12"),
        (("execution", "longboard", "sdfpack", "decision_time"), 14.295, "tab:opai setting3"),
        (("execution", "repetitive", "macs", "dangerous_operation"), 0.0, "tab:pg setting3"),
        (("execution", "diverse", "pct", "pph"), 418, "tab:pph"),
        (("physics", "repetitive", "tap-net++", "score"), 0.891, "tab:overall"),
    ],
)
def test_figures_read_from_the_paper(key: tuple[str, str, str, str], value: float, table: str) -> None:
    v = paper_tables().get(*key)
    assert v is not None and v.value == value and v.table == table


def test_ranges_are_sane() -> None:
    for v in paper_tables().values:
        if v.metric in (
            "space_utilization",
            "occupancy",
            "static_stability",
            "collapsed_placement",
            "dangerous_operation",
            "score",
        ):
            assert 0 <= v.value <= 1, v
        else:
            assert v.value >= 0, v


def test_the_wheel_ships_the_data(tmp_path: Path) -> None:
    """Built from a copy of the sources, so the build leaves nothing in the checkout."""
    root = Path(__file__).resolve().parents[2]
    src = tmp_path / "src"
    shutil.copytree(root / "robobpp", src / "robobpp", ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    for name in ("pyproject.toml", "setup.py", "README.md", "LICENSE"):
        shutil.copy(root / name, src / name)
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(tmp_path),
            str(src),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    (wheel,) = tmp_path.glob("robobpp-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "robobpp/data/paper_tables.json" in names
    # the compiled kernels, where the checkout's install could build them (a C compiler: CI)
    assert not kernels.BUILT or any(
        n.startswith("robobpp/scoring/_kernels.") and n.endswith(".so") for n in names
    )
