"""``robobpp datasets``: fetch and convert the RoboBPP data, describe it, build the private evaluation set."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from robobpp.cli.common import DatasetOpt, fail, parse_choices, table_console

app = typer.Typer(no_args_is_help=True, help="RoboBPP datasets: fetch, describe, build the private split.")
console = Console(stderr=True)

DataDir = Annotated[
    Path | None,
    typer.Option("--data-dir", envvar="ROBOBPP_DATA_DIR", help="Data cache (default: the user cache dir)."),
]


def register(root: typer.Typer) -> None:
    """Mounted by the root app as ``robobpp datasets`` (kept for symmetry with the other areas)."""
    return None


def _use_data_dir(path: Path | None) -> None:
    # The library reads ROBOBPP_DATA_DIR, so one option steers every call below.
    if path is not None:
        os.environ["ROBOBPP_DATA_DIR"] = str(path)


def _fail(exc: Exception) -> None:
    fail(escape(str(exc)), code=1)


@app.command()
def fetch(
    data_dir: DataDir = None,
    force: Annotated[
        bool, typer.Option("--force", help="Re-download and rebuild even if the cache is valid.")
    ] = False,
    wheel: Annotated[
        Path | None, typer.Option(help="Import from this local packsim-0.0.4 wheel instead of downloading.")
    ] = None,
) -> None:
    """Download packsim==0.0.4, verify its checksums, convert the three datasets into the cache."""
    from robobpp.datasets import DatasetError
    from robobpp.datasets.cache import converted_dir
    from robobpp.datasets.importer import fetch as do_fetch

    _use_data_dir(data_dir)
    try:
        with console.status("fetching RoboBPP data") as status:
            manifest = do_fetch(force=force, wheel=wheel, notify=lambda m: status.update(m))
    except DatasetError as exc:
        _fail(exc)
    table = Table(title=f"RoboBPP data in {converted_dir()}")
    for column in ("dataset", "records", "usable", "train", "test", "notes"):
        table.add_column(column, justify="left" if column in ("dataset", "notes") else "right")
    for name, facts in manifest["datasets"].items():
        notes = []
        if "duplicates_flagged" in facts:
            notes.append(f"{facts['duplicates_flagged']} duplicate records flagged")
        if "zero_rows_excluded" in facts:
            notes.append(f"{facts['zero_rows_excluded']} zero-size rows excluded")
        if "unplaceable" in facts:
            notes.append(f"{facts['unplaceable']} unplaceable panels excluded from the pools")
        usable = facts.get("usable", facts["records"])
        table.add_row(
            name,
            f"{facts['records']:,}",
            f"{usable:,}",
            f"{facts['train']:,}",
            f"{facts['test']:,}",
            "; ".join(notes),
        )
    table_console().print(table)


def _quartiles(values: np.ndarray) -> str:
    q1, q2, q3 = np.percentile(values, [25, 50, 75])
    return f"{q1:.1f} / {q2:.1f} / {q3:.1f}"


@app.command()
def info(
    dataset: DatasetOpt = "all",
    data_dir: DataDir = None,
) -> None:
    """Per dataset and split: records, boxes, distinct sizes and dimension quartiles (cm)."""
    from robobpp.datasets import DATASETS, DatasetError, load_pool

    names = parse_choices(dataset, DATASETS, "dataset")
    _use_data_dir(data_dir)
    table = Table(title="RoboBPP datasets (sizes in cm; quartiles Q1 / median / Q3 over the pool's boxes)")
    for column in (
        "dataset",
        "split",
        "records",
        "boxes",
        "distinct sizes",
        "length",
        "width",
        "height",
        "notes",
    ):
        table.add_column(
            column, justify="right" if column in ("records", "boxes", "distinct sizes") else "left"
        )
    try:
        for name in names:
            spec = DATASETS[name]
            for split in spec.splits:
                pool = load_pool(name, split)
                distinct = len(np.unique(pool.dims, axis=0))
                labels = {"unplaceable": "unplaceable, excluded"}  # fit in no orientation: not in the pool
                notes = [f"{labels.get(k, k.replace('_', ' '))}: {v}" for k, v in pool.notes.items() if v]
                table.add_row(
                    name,
                    split,
                    f"{pool.records:,}",
                    f"{len(pool):,}",
                    f"{distinct:,}",
                    *(_quartiles(pool.dims[:, i]) for i in range(3)),
                    ", ".join(notes),
                )
    except DatasetError as exc:
        _fail(exc)
    table_console().print(table)


@app.command("build-private")
def build_private(
    root: Annotated[Path, typer.Option(help="Where to write the private evaluation set.")] = Path(
        "datasets_private"
    ),
    seed: Annotated[
        int | None, typer.Option(min=0, help="Sampling seed (default: a fresh secret one; keep it secret).")
    ] = None,
    groups: Annotated[int, typer.Option(min=1, max=10_000, help="Groups per dataset.")] = 30,
    dataset: DatasetOpt = "all",
    data_dir: DataDir = None,
) -> None:
    """Draw the evaluation groups of each dataset from its test pool and write them under ROOT."""
    from robobpp.datasets import DATASETS, DatasetError
    from robobpp.datasets import build_private as do_build

    names = parse_choices(dataset, DATASETS, "dataset")
    _use_data_dir(data_dir)
    if root.exists() and not root.is_dir():
        fail(escape(f"{root}: exists and is not a directory"), code=1)
    try:
        written = do_build(root, seed=seed, groups=groups, datasets=names)
    except (DatasetError, OSError) as exc:
        _fail(exc)
    for name, path in written.items():
        console.print(f"{name}: {groups} groups → {escape(str(path))}")
