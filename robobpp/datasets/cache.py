"""The data cache: where the fetched wheel and the converted datasets live, and how they are trusted.

Layout under ``data_dir()`` (``ROBOBPP_DATA_DIR``, default ``$XDG_CACHE_HOME/robobpp`` or ``~/.cache/robobpp``)::

    wheels/packsim-0.0.4-py3-none-any.whl   the verified source wheel (kept: re-converting needs no network)
    packsim-0.0.4/manifest.json             what was converted, from what, and the sha256 of every file
    packsim-0.0.4/<dataset>.npz             one compressed array file per dataset (no pickles)

The converted directory only ever appears whole: it is written to a temp directory beside it and renamed.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from robobpp.datasets.errors import CacheCorruptError
from robobpp.datasets.sources import sha256_file

MANIFEST = "manifest.json"
CACHE_FORMAT = "robobpp-data/1"
CONVERTED_DIR = "packsim-0.0.4"


def data_dir() -> Path:
    """The cache root; an explicit ``ROBOBPP_DATA_DIR`` wins so tests and servers can isolate it."""
    explicit = os.environ.get("ROBOBPP_DATA_DIR")
    if explicit:
        return Path(explicit).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "robobpp"


def converted_dir(root: Path | None = None) -> Path:
    return (root or data_dir()) / CONVERTED_DIR


def wheels_dir(root: Path | None = None) -> Path:
    return (root or data_dir()) / "wheels"


@contextlib.contextmanager
def locked(root: Path) -> Iterator[None]:
    """An exclusive lock on the cache so parallel processes (test workers, server workers) fetch once."""
    root.mkdir(parents=True, exist_ok=True)
    with (root / ".lock").open("a") as fh:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - non-POSIX: fall back to the atomic rename alone
            yield
            return
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def read_manifest(directory: Path) -> dict[str, Any] | None:
    """The manifest, or None when the converted directory does not exist yet (fetch on first use)."""
    path = directory / MANIFEST
    if not path.is_file():
        return None
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise CacheCorruptError(
            f"{path}: unreadable manifest ({exc}); run `robobpp datasets fetch --force`"
        ) from exc
    if not isinstance(manifest, dict) or manifest.get("format") != CACHE_FORMAT:
        raise CacheCorruptError(
            f"{path}: not a {CACHE_FORMAT} manifest; run `robobpp datasets fetch --force` to rebuild the cache"
        )
    return manifest


_verified: dict[tuple[str, int, int], str] = {}


def verify_converted(directory: Path, manifest: dict[str, Any], filename: str) -> Path:
    """Check one converted file against its manifest entry; memoised per (path, mtime, size) in-process."""
    entry = manifest.get("files", {}).get(filename)
    path = directory / filename
    hint = "the data cache is corrupted; run `robobpp datasets fetch --force` to rebuild it"
    if entry is None:
        raise CacheCorruptError(f"{path}: not listed in {directory / MANIFEST}; {hint}")
    if not path.is_file():
        raise CacheCorruptError(f"{path}: missing (expected sha256 {entry['sha256']}); {hint}")
    stat = path.stat()
    key = (str(path), stat.st_mtime_ns, stat.st_size)
    if _verified.get(key) == entry["sha256"]:
        return path
    actual = sha256_file(path)
    if actual != entry["sha256"]:
        raise CacheCorruptError(
            f"{path}: sha256 mismatch (size {stat.st_size} bytes): expected {entry['sha256']}, got {actual}; {hint}"
        )
    _verified[key] = actual
    return path


def publish(build: Path, target: Path) -> None:
    """Replace ``target`` by the fully written ``build`` directory with renames only."""
    if target.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{target.name}-old-", dir=target.parent))
        os.replace(target, old / "x")
        os.replace(build, target)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(build, target)
