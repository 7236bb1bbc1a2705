"""``robobpp datasets fetch``: get the pinned packsim wheel, verify it, convert its data with our readers.

Pipeline: wheel (pip download into a temp dir, or a local file) → sha256 of the wheel → sha256 of each data
file inside → our readers → compact ``.npz`` per dataset + manifest, written to a temp directory and renamed
into place. Any failure leaves the previous cache (or none) untouched.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import zipfile
from collections import Counter
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from robobpp.core import ContainerSpec
from robobpp.datasets import readers
from robobpp.datasets.cache import (
    CACHE_FORMAT,
    MANIFEST,
    converted_dir,
    data_dir,
    locked,
    publish,
    read_manifest,
    verify_converted,
    wheels_dir,
)
from robobpp.datasets.errors import ChecksumError, FetchError, SourceFormatError
from robobpp.datasets.registry import DATASETS
from robobpp.datasets.sources import (
    PACKSIM_REQUIREMENT,
    SOURCE_SHA256,
    WHEEL_NAME,
    WHEEL_SHA256,
    download_wheel,
    sha256_file,
    verify_source,
    verify_wheel,
)

Notify = Callable[[str], None]

#: Counts the importer must find (docs/datasets.md, "Counts observed"); a mismatch means our reader is wrong, so it stops.
EXPECTED = {
    "repetitive": {"records": 16_767, "test": 3_353, "duplicates": 58},
    "diverse": {"records": 6_849, "zero_rows": 48, "usable": 6_801},
    "longboard": {"records": 293, "train": 234, "test": 59},
}
DIVERSE_SPLIT_SALT = "robobpp-diverse:"
DIVERSE_TEST_PERCENT = 20
SPLIT_CODES = {"train": 0, "test": 1}


def diverse_is_test(code: str) -> bool:
    """Stable 80/20 split of the Diverse SKUs by a hash of their code (no split files exist)."""
    digest = hashlib.sha256((DIVERSE_SPLIT_SALT + code).encode("utf-8")).digest()
    return int.from_bytes(digest[:8], "big") % 100 < DIVERSE_TEST_PERCENT


def _normalise(raw: np.ndarray) -> dict[str, np.ndarray]:
    """length = longer horizontal side, width = shorter, height as given (boxes are never tipped)."""
    return {
        "length": np.maximum(raw[:, 0], raw[:, 1]),
        "width": np.minimum(raw[:, 0], raw[:, 1]),
        "height": raw[:, 2].copy(),
        "raw_length": raw[:, 0].copy(),
        "raw_width": raw[:, 1].copy(),
    }


def _expect(dataset: str, key: str, actual: int) -> None:
    expected = EXPECTED[dataset][key]
    if actual != expected:
        raise SourceFormatError(f"{dataset}: found {actual} {key}, expected {expected}")


def fits_container(dims: np.ndarray, container: ContainerSpec) -> np.ndarray:
    """Which (n, 3) boxes fit the container in some orientation (upright; they are never tipped)."""
    length, width, height = dims[:, 0], dims[:, 1], dims[:, 2]
    c = container
    flat = ((length <= c.length) & (width <= c.width)) | ((width <= c.length) & (length <= c.width))
    return flat & (height <= c.height)


def convert_repetitive(files: dict[str, bytes]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    name = "packsim/data/time_series/pg.xlsx"
    rec = readers.read_pick_records(files[name], name)
    n = len(rec["record_id"])
    _expect("repetitive", "records", n)
    _expect("repetitive", "duplicates", int(rec["duplicate"].sum()))
    test_ids = readers.read_record_ids(files["packsim/data/time_series/pg_test.xlsx"], "pg_test.xlsx")
    train_ids = readers.read_record_ids(files["packsim/data/time_series/pg_train.xlsx"], "pg_train.xlsx")
    _expect("repetitive", "test", len(test_ids))
    k = len(test_ids)
    if not (
        np.array_equal(test_ids, rec["record_id"][:k]) and np.array_equal(train_ids, rec["record_id"][k:])
    ):
        raise SourceFormatError("pg_test/pg_train are not the earliest 20 % / the rest of pg.xlsx")
    split = np.zeros(n, dtype=np.int8)
    split[:k] = SPLIT_CODES["test"]
    arrays = (
        {k2: v for k2, v in rec.items() if k2 != "dims_raw"} | _normalise(rec["dims_raw"]) | {"split": split}
    )
    facts = {
        "records": n,
        "duplicates_flagged": int(rec["duplicate"].sum()),
        "boxes": int(rec["quantity"].sum()),
        "quantity_range": [int(rec["quantity"].min()), int(rec["quantity"].max())],
        "mass_range_kg": [float(rec["mass"].min()), float(rec["mass"].max())],
        "time_range": [str(rec["start_time"][0]), str(rec["start_time"][-1])],
    }
    return arrays, facts


def convert_diverse(files: dict[str, bytes]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    name = "packsim/data/occupancy/deli.xlsx"
    skus, zero_rows = readers.read_skus(files[name], name)
    usable = len(skus["code"])
    _expect("diverse", "records", usable + zero_rows)
    _expect("diverse", "zero_rows", zero_rows)
    _expect("diverse", "usable", usable)
    split = np.asarray(
        [SPLIT_CODES["test"] if diverse_is_test(c) else 0 for c in skus["code"]], dtype=np.int8
    )
    raw = skus.pop("dims_raw")
    w_longest = (raw[:, 1] >= raw[:, 0]) & (raw[:, 1] >= raw[:, 2])
    facts = {
        "records": usable + zero_rows,
        "zero_rows_excluded": zero_rows,
        "usable": usable,
        "w_column_longest_share": round(float(w_longest.mean()), 4),
        "w_column_at_least_l_share": round(float((raw[:, 1] >= raw[:, 0]).mean()), 4),
    }
    return skus | _normalise(raw) | {"split": split}, facts


def convert_longboard(files: dict[str, bytes]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    base = "packsim/data/flat_long/"
    panels = readers.read_panels(files[base + "opai.txt"], "opai.txt")
    train = readers.read_panels(files[base + "opai_train.txt"], "opai_train.txt")
    test = readers.read_panels(files[base + "opai_test.txt"], "opai_test.txt")
    _expect("longboard", "records", len(panels))
    _expect("longboard", "train", len(train))
    _expect("longboard", "test", len(test))
    if Counter(map(tuple, panels.tolist())) != Counter(map(tuple, np.vstack([train, test]).tolist())):
        raise SourceFormatError("opai_train.txt + opai_test.txt are not a partition of opai.txt")
    raw = np.vstack([train, test])
    split = np.asarray([0] * len(train) + [1] * len(test), dtype=np.int8)
    arrays = _normalise(raw) | {"split": split}
    dims = np.stack([arrays["length"], arrays["width"], arrays["height"]], axis=1)
    fits = fits_container(dims, DATASETS["longboard"].container)
    facts = {
        "records": len(panels),
        "unplaceable": int((~fits).sum()),
        "distinct_sizes": len(set(map(tuple, raw))),
    }
    return arrays, facts


CONVERTERS = {"repetitive": convert_repetitive, "diverse": convert_diverse, "longboard": convert_longboard}


def read_wheel_sources(wheel: Path) -> dict[str, bytes]:
    """Every data file we need, read from the wheel and checked against its pinned sha256."""
    try:
        archive = zipfile.ZipFile(wheel)
    except (zipfile.BadZipFile, OSError) as exc:
        raise ChecksumError(f"{wheel.name}: not a readable wheel/zip archive ({exc})") from exc
    with archive:
        names = set(archive.namelist())
        out = {}
        for name in SOURCE_SHA256:
            try:
                data = archive.read(name) if name in names else None
            except (zipfile.BadZipFile, OSError, EOFError) as exc:  # a damaged member (CRC error, cut stream)
                raise ChecksumError(
                    f"{name} in {wheel.name}: unreadable ({exc}); truncated or altered"
                ) from exc
            out[name] = verify_source(name, data, wheel)
    return out


def convert(wheel: Path, target: Path, wheel_sha256: str | None, notify: Notify) -> dict[str, Any]:
    """Write the converted cache for ``wheel`` to ``target`` atomically; returns the manifest."""
    files = read_wheel_sources(wheel)
    target.parent.mkdir(parents=True, exist_ok=True)
    build = Path(tempfile.mkdtemp(prefix=f".{target.name}-build-", dir=target.parent))
    os.chmod(build, 0o755)  # mkdtemp's 0700 would hide a shared cache from other users
    try:
        manifest: dict[str, Any] = {
            "format": CACHE_FORMAT,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "source": {
                "requirement": PACKSIM_REQUIREMENT,
                "wheel": wheel.name,
                "sha256": wheel_sha256 or sha256_file(wheel),
                "files": dict(SOURCE_SHA256),
            },
            "conventions": {
                "units": "cm, kg",
                "dims": "length = longer horizontal side, width = shorter, height = vertical as given",
                "split_codes": SPLIT_CODES,
            },
            "files": {},
            "datasets": {},
        }
        for dataset, converter in CONVERTERS.items():
            notify(f"converting {dataset}")
            arrays, facts = converter(files)
            filename = f"{dataset}.npz"
            # numpy's stub types **kwds as if a key could be its allow_pickle flag; every value is an array
            np.savez_compressed(build / filename, **arrays)  # type: ignore[arg-type]
            split = arrays["split"]
            facts |= {s: int((split == code).sum()) for s, code in SPLIT_CODES.items()}
            manifest["datasets"][dataset] = facts
            manifest["files"][filename] = {
                "sha256": sha256_file(build / filename),
                "bytes": (build / filename).stat().st_size,
            }
        (build / MANIFEST).write_text(json.dumps(manifest, indent=2, ensure_ascii=False), encoding="utf-8")
        publish(build, target)
    finally:
        shutil.rmtree(build, ignore_errors=True)
    return manifest


def cache_is_valid(root: Path | None = None) -> bool:
    """True when the converted cache exists and every file matches its manifest."""
    directory = converted_dir(root)
    manifest = read_manifest(directory)
    if manifest is None:
        return False
    for filename in manifest.get("files", {}):
        verify_converted(directory, manifest, filename)
    return set(manifest.get("datasets", {})) == set(CONVERTERS)


def _keep_wheel(source: Path, target: Path) -> None:
    if target.exists() and target.resolve() == source.resolve():
        return
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_suffix(".partial")
    shutil.copyfile(source, partial)
    partial.replace(target)


def fetch(
    root: Path | None = None,
    *,
    force: bool = False,
    wheel: Path | None = None,
    wheel_sha256: str | None = WHEEL_SHA256,
    notify: Notify | None = None,
) -> dict[str, Any]:
    """Make the converted cache exist and be valid; returns its manifest.

    ``wheel`` imports from a local file instead of downloading (offline machines, tests). ``force``
    re-downloads the wheel and rebuilds the cache even when a valid one exists. ``wheel_sha256=None``
    skips only the whole-wheel hash (the per-file hashes still apply); it exists so tests can exercise the
    per-file checks with a rebuilt archive.
    """
    say = notify or (lambda _msg: None)
    root = root or data_dir()
    with locked(root):
        directory = converted_dir(root)
        if not force and wheel is None:
            try:
                if cache_is_valid(root):
                    manifest = read_manifest(directory)
                    assert manifest is not None
                    return manifest
            except Exception:  # noqa: BLE001 - a corrupt cache, however it fails, is rebuilt below from a verified wheel
                pass
        if wheel is not None:
            source = Path(wheel)
            if not source.is_file():
                raise FetchError(f"{source}: wheel file not found")
            if wheel_sha256 is not None:
                say(f"verifying {source.name}")
                verify_wheel(source, wheel_sha256)
            if wheel_sha256 == WHEEL_SHA256:  # keep the verified wheel so a later rebuild needs no network
                _keep_wheel(source, wheels_dir(root) / WHEEL_NAME)
        else:
            source = wheels_dir(root) / WHEEL_NAME
            if force or not source.is_file():
                say(f"downloading {PACKSIM_REQUIREMENT} from the package index")
                source = download_wheel(wheels_dir(root))
            else:
                say(f"verifying {source}")
                verify_wheel(source)
        return convert(source, directory, wheel_sha256, say)
