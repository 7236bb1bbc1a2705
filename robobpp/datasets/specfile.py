"""Episode-set files (JSON, or CSV for hand-written synthetic boxes) with strict validation at load.

Private evaluation sets and synthetic sets share this one format so one validator guards both: a zero,
negative, non-finite or non-numeric size is refused with the file, group, box and field named, before any
``Box`` exists.
"""

from __future__ import annotations

import csv
import json
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from robobpp.core import Box, ContainerSpec, EpisodeSpec
from robobpp.datasets.errors import SpecFileError

SPEC_FORMAT = "robobpp-episodes/1"
BOX_FIELDS = ("length", "width", "height", "mass")


def _positive(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SpecFileError(f"{where} must be a number, got {value!r}")
    if not math.isfinite(value) or value <= 0:
        raise SpecFileError(f"{where} must be a finite number > 0, got {value!r}")
    return float(value)


def to_json(specs: Sequence[EpisodeSpec]) -> dict[str, Any]:
    """One JSON document for episodes that share dataset, split, container and threshold."""
    if not specs:
        raise ValueError("no episodes to write")
    first = specs[0]
    for spec in specs:
        same = (spec.dataset, spec.split, spec.container, spec.collapse_threshold_cm)
        if same != (first.dataset, first.split, first.container, first.collapse_threshold_cm):
            raise ValueError("all episodes of one file must share dataset, split, container and threshold")
    c = first.container
    return {
        "format": SPEC_FORMAT,
        "dataset": first.dataset,
        "split": first.split,
        "container": {"length": c.length, "width": c.width, "height": c.height},
        "collapse_threshold_cm": first.collapse_threshold_cm,
        **({"sampler": first.sampler_version} if first.sampler_version is not None else {}),
        "groups": [
            {
                "group": s.group,
                "seed": s.seed,
                "boxes": [[b.length, b.width, b.height, b.mass] for b in s.boxes],
            }
            for s in specs
        ],
    }


def write_json_atomic(path: Path, document: dict[str, Any]) -> None:
    """Write via a temp file in the same directory and rename, so readers never see half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}-", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(document, fh, separators=(",", ":"), allow_nan=False)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_specs(path: Path, specs: Sequence[EpisodeSpec]) -> None:
    write_json_atomic(Path(path), to_json(specs))


def from_json(document: Any, source: str) -> list[EpisodeSpec]:
    """Validate and build the episodes of a JSON document; ``source`` names the file in errors."""
    if not isinstance(document, dict) or document.get("format") != SPEC_FORMAT:
        raise SpecFileError(f"{source}: not a {SPEC_FORMAT} document")
    for key in ("dataset", "split"):
        if not isinstance(document.get(key), str) or not document[key]:
            raise SpecFileError(f"{source}: {key!r} must be a non-empty string")
    raw_container = document.get("container")
    if not isinstance(raw_container, dict):
        raise SpecFileError(f"{source}: 'container' must be an object with length, width, height")
    container = ContainerSpec(
        *(_positive(raw_container.get(k), f"{source}: container {k}") for k in ("length", "width", "height"))
    )
    threshold = _positive(document.get("collapse_threshold_cm"), f"{source}: collapse_threshold_cm")
    groups = document.get("groups")
    if not isinstance(groups, list) or not groups:
        raise SpecFileError(f"{source}: 'groups' must be a non-empty list")
    sampler = document.get("sampler")
    if sampler is not None and (not isinstance(sampler, str) or not sampler):
        raise SpecFileError(f"{source}: 'sampler' must be a non-empty string (the sampler version)")
    out = []
    for position, group in enumerate(groups):
        where = f"{source}: group {position}"
        if not isinstance(group, dict) or not isinstance(group.get("boxes"), list) or not group["boxes"]:
            raise SpecFileError(f"{where}: expected an object with a non-empty 'boxes' list")
        number, seed = group.get("group", position), group.get("seed", 0)
        for key, value in (("group", number), ("seed", seed)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise SpecFileError(f"{where}: {key} must be an integer >= 0, got {value!r}")
        boxes = tuple(_box(raw, f"{where} box {i}") for i, raw in enumerate(group["boxes"]))
        out.append(
            EpisodeSpec(
                document["dataset"], document["split"], number, boxes, container, threshold, seed, sampler
            )
        )
    return out


def _box(raw: Any, where: str) -> Box:
    if isinstance(raw, dict):
        raw = [raw.get(k, 1.0 if k == "mass" else None) for k in BOX_FIELDS]
    if not isinstance(raw, list | tuple) or len(raw) not in (3, 4):
        raise SpecFileError(f"{where}: expected [length, width, height(, mass)], got {raw!r}")
    values = [_positive(v, f"{where} {name}") for v, name in zip(raw, BOX_FIELDS, strict=False)]
    return Box(*values)


def read_json(path: Path) -> list[EpisodeSpec]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SpecFileError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    try:
        document = json.loads(text)  # NaN/Infinity literals parse here and are refused by validation
    except ValueError as exc:
        raise SpecFileError(f"{path}: invalid JSON ({exc})") from exc
    return from_json(document, str(path))


def read_csv(
    path: Path,
    container: ContainerSpec,
    collapse_threshold_cm: float = 7.0,
    dataset: str = "synthetic",
    split: str = "train",
) -> list[EpisodeSpec]:
    """Boxes as CSV rows ``group,length,width,height[,mass]`` (header required); groups in first-seen order."""
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
            header = list(rows[0]) if rows else []
    except OSError as exc:
        raise SpecFileError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    missing = {"group", "length", "width", "height"} - set(header)
    if not rows or missing:
        raise SpecFileError(
            f"{path}: expected a header group,length,width,height[,mass] and rows (missing {missing})"
        )
    groups: dict[int, list[Box]] = {}
    for line, row in enumerate(rows, start=2):
        where = f"{path} line {line}"
        try:
            group = int(row["group"])
            values = [float(row[k]) for k in BOX_FIELDS if k in row and row[k] not in (None, "")]
        except (TypeError, ValueError):
            raise SpecFileError(f"{where}: group must be an integer and sizes numbers, got {row}") from None
        if group < 0:
            raise SpecFileError(f"{where}: group must be >= 0, got {group}")
        groups.setdefault(group, []).append(_box(values, where))
    threshold = _positive(collapse_threshold_cm, "collapse_threshold_cm")
    return [EpisodeSpec(dataset, split, g, tuple(b), container, threshold, 0) for g, b in groups.items()]
