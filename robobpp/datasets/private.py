"""The private evaluation set: 30 groups per dataset from the test pool, drawn with a secret seed.

``build_private`` writes ``<root>/<dataset>.json`` (episode-set format) and ``<root>/manifest.json`` with
their sha256; ``load_private`` refuses a file that is missing, altered, or disagrees with the registry.
The seed itself is not stored: the per-group seeds in the files are one-way derivations of it.

Each manifest entry records the sampler version that drew it. A set drawn by another version is refused at load
(version 1's Repetitive groups are windows of the public test pool: docs/datasets.md, "Private groups nobody can
look up"); ``robobpp serve`` rebuilds such a set at start (:func:`stale_datasets`).
"""

from __future__ import annotations

import json
import secrets
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from robobpp.core import EpisodeSpec
from robobpp.datasets.errors import SpecFileError
from robobpp.datasets.registry import DATASETS, EVAL_GROUPS, GROUP_SIZE, get_dataset
from robobpp.datasets.sampling import SAMPLER_VERSION, episode_specs
from robobpp.datasets.sources import WHEEL_SHA256, sha256_file
from robobpp.datasets.specfile import read_json, write_json_atomic, write_specs

PRIVATE_FORMAT = "robobpp-private/1"
#: Subdirectory of the private root holding the hold-out draw: the same format, drawn from the same test
#: pool with another secret seed, and played only by verifications of top entries (docs/server.md).
HOLDOUT_DIR = "holdout"
PRIVATE_SPLIT = "test"
HINT = "run `robobpp datasets build-private` to (re)build it"
#: The sampler version of an entry written before entries recorded theirs.
UNRECORDED_SAMPLER = "1"


def build_private(
    root: Path, seed: int | None = None, groups: int = EVAL_GROUPS, datasets: list[str] | None = None
) -> dict[str, Path]:
    """Draw and write the evaluation set; ``seed=None`` takes a fresh secret seed. Returns the files."""
    root = Path(root)
    names = datasets or list(DATASETS)
    for name in names:
        get_dataset(name)
    if seed is None:
        seed = secrets.randbits(63)
    written = {}
    entries: dict[str, Any] = {}
    for name in names:
        specs = episode_specs(name, PRIVATE_SPLIT, groups=groups, seed=seed)
        path = root / f"{name}.json"
        write_specs(path, specs)
        written[name] = path
        entries[name] = {
            "file": path.name,
            "sha256": sha256_file(path),
            "groups": groups,
            "group_size": GROUP_SIZE,
            "sampler": SAMPLER_VERSION,
        }
    manifest_path = root / "manifest.json"
    manifest = _read_manifest(manifest_path) if manifest_path.is_file() else {}
    datasets_entry = manifest.get("datasets", {}) if isinstance(manifest.get("datasets"), dict) else {}
    write_json_atomic(
        manifest_path,
        {
            "format": PRIVATE_FORMAT,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "source_wheel_sha256": WHEEL_SHA256,
            "datasets": datasets_entry | entries,
        },
    )
    return written


def _read_manifest(path: Path) -> dict[str, Any]:
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise SpecFileError(f"{path}: unreadable private-set manifest ({exc}); {HINT}") from exc
    if not isinstance(manifest, dict) or manifest.get("format") != PRIVATE_FORMAT:
        raise SpecFileError(f"{path}: not a {PRIVATE_FORMAT} manifest; {HINT}")
    return manifest


def _sampler_of(entry: dict[str, Any]) -> str:
    return str(entry.get("sampler", UNRECORDED_SAMPLER))


def stale_datasets(root: Path, datasets: list[str]) -> list[str]:
    """Those of ``datasets`` that the set in ``root`` lacks or drew with another sampler version (all of them
    when there is no manifest); an unreadable manifest raises :class:`SpecFileError`."""
    manifest_path = Path(root) / "manifest.json"
    if not manifest_path.is_file():
        return list(datasets)
    entries = _read_manifest(manifest_path).get("datasets", {})
    return [
        name
        for name in datasets
        if not isinstance(entries.get(name), dict) or _sampler_of(entries[name]) != SAMPLER_VERSION
    ]


def load_private(dataset: str, root: Path) -> list[EpisodeSpec]:
    """The private episodes of ``dataset``, after checking checksum, container, threshold and sizes."""
    spec = get_dataset(dataset)
    root = Path(root)
    manifest_path = root / "manifest.json"
    if not manifest_path.is_file():
        raise SpecFileError(f"{manifest_path}: no private evaluation set here; {HINT}")
    entry = _read_manifest(manifest_path).get("datasets", {}).get(dataset)
    if not isinstance(entry, dict):
        raise SpecFileError(f"{manifest_path}: has no entry for {dataset}; {HINT}")
    if _sampler_of(entry) != SAMPLER_VERSION:
        raise SpecFileError(
            f"{manifest_path}: {dataset} was drawn by sampler version {_sampler_of(entry)}, this robobpp "
            f"draws with version {SAMPLER_VERSION} (version 1's Repetitive groups can be looked up in the "
            f"public data); {HINT} (`robobpp serve` rebuilds it at start)"
        )
    path = root / str(entry.get("file"))
    if not path.is_file():
        raise SpecFileError(f"{path}: missing (expected sha256 {entry.get('sha256')}); {HINT}")
    actual = sha256_file(path)
    if actual != entry.get("sha256"):
        raise SpecFileError(f"{path}: sha256 mismatch: expected {entry.get('sha256')}, got {actual}; {HINT}")
    specs = read_json(path)
    for s in specs:
        if s.dataset != dataset or s.split != PRIVATE_SPLIT:
            raise SpecFileError(
                f"{path}: holds {s.dataset}/{s.split} episodes, expected {dataset}/{PRIVATE_SPLIT}"
            )
        if s.sampler_version not in (None, SAMPLER_VERSION):
            raise SpecFileError(
                f"{path}: drawn by sampler version {s.sampler_version}, not {SAMPLER_VERSION}; {HINT}"
            )
        if s.container != spec.container or s.collapse_threshold_cm != spec.collapse_threshold_cm:
            raise SpecFileError(
                f"{path}: container or threshold differ from the registry's {dataset}; {HINT}"
            )
        if len(s.boxes) != entry.get("group_size", GROUP_SIZE):
            raise SpecFileError(f"{path}: group {s.group} has {len(s.boxes)} boxes, expected {GROUP_SIZE}")
    if len(specs) != entry.get("groups"):
        raise SpecFileError(f"{path}: {len(specs)} groups, manifest says {entry.get('groups')}; {HINT}")
    return specs
