"""What produced a result: recorded with every result (docs/benchmark.md, "Provenance").

A figure can be compared with another only when the same rules produced both. Each result therefore carries
the versions of everything that decides its figures: the robobpp code (and its git commit when it runs from a
checkout), the datasets it drew from, the physics, the Math Pack rules, the group sampler, the stable score's
anchors; and what was run: protocol, lookahead (the next boxes the policy saw), split, seed, groups. Boards
never mix versions of the physics, the rules or the sampler (robobpp/db/queries.py), nor lookaheads (each has
boards of its own).

It also names the machine that ran the episodes (CPU model, logical cores): Decision Time is wall-clock and
means something only beside it. The machine is not a rule: boards do not split on it (``recorded_rules``).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import platform
import subprocess
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from robobpp import __version__

#: The fields of a result's provenance, in the order they are shown.
FIELDS = (
    "robobpp",
    "commit",
    "datasets_manifest_sha256",
    "machine",
    "physics",
    "math_rules",
    "sampler",
    "anchors",
    "protocol",
    "lookahead",
    "split",
    "seed",
    "groups",
)


@functools.cache
def git_commit() -> str | None:
    """The checkout's commit when robobpp runs from a git checkout (``-dirty`` with uncommitted changes to
    tracked files), else None (an installed wheel)."""
    root = Path(__file__).resolve().parent.parent
    if not (root / ".git").exists():
        return None
    try:
        head = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{head}-dirty" if dirty else head or None


def version_line() -> str:
    """``robobpp --version``: the version, and the commit when run from a checkout."""
    commit = git_commit()
    return f"robobpp {__version__}" + (f" (commit {commit})" if commit else "")


def datasets_manifest_sha256(root: Path | None = None) -> str | None:
    """SHA-256 of the data cache's manifest (canonical JSON), or None when the data was never fetched.

    The manifest says what was converted from which wheel (its sha256 and every source file's), the
    conventions, and each dataset's facts. Its creation time and the converted files' own hashes are left
    out: those change with every conversion (the archives hold timestamps), so two machines that converted
    the same wheel with the same importer get the same figure.
    """
    from robobpp.datasets.cache import converted_dir, read_manifest

    try:
        manifest = read_manifest(converted_dir(root))
    except Exception:  # noqa: BLE001 - a broken cache has no fingerprint; its use fails on its own
        return None
    if manifest is None:
        return None
    content = {k: v for k, v in manifest.items() if k not in ("created", "files")}
    return hashlib.sha256(json.dumps(content, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def cpu_model(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The CPU's marketing name ("AMD EPYC 7763 64-Core Processor"): Linux's ``model name``, else what
    :mod:`platform` knows (often only the architecture, "arm64", on macOS and on ARM Linux)."""
    try:
        for line in cpuinfo.read_text(encoding="utf-8", errors="replace").splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                return " ".join(value.split())  # some kernels pad the name with runs of spaces
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


@functools.cache
def machine() -> str:
    """The machine as a provenance shows it: "<CPU model> (<n> logical cores)", without commas so that a list
    of several machines (:func:`merged`) still reads as one line."""
    cores = os.cpu_count()
    return f"{cpu_model().replace(',', ' ')} ({cores or '?'} logical cores)"


def environment() -> dict[str, str | None]:
    """The parts of a provenance that come from the running installation rather than from the episodes:
    what code and data ran, and on which machine (for Decision Time, docs/reporting.md)."""
    return {
        "robobpp": __version__,
        "commit": git_commit(),
        "datasets_manifest_sha256": datasets_manifest_sha256(),
        "machine": machine(),
    }


def merged(values: Iterable[Any]) -> Any:
    """One value when all agree (None ignored), a sorted list when they differ, None when there is none."""
    seen = sorted({json.dumps(v, sort_keys=True) for v in values if v is not None})
    out = [json.loads(v) for v in seen]
    return None if not out else out[0] if len(out) == 1 else out


def merge(records: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Several provenances (episodes of a run, runs of a submission) as one, field by field (:func:`merged`)."""
    rows = list(records)
    keys = [k for k in FIELDS if any(k in r for r in rows)] + sorted(
        {k for r in rows for k in r if k not in FIELDS}
    )
    return {k: merged(r.get(k) for r in rows) for k in keys}


def of_results(
    results: Iterable[Any],
    *,
    protocol: str,
    split: str,
    seed: int | None,
    groups: int,
    lookahead: int = 0,
) -> dict[str, Any]:
    """The provenance of a local run (``robobpp evaluate``) from its ``EpisodeResult``s; ``protocol`` is the
    one asked for (the paper protocol's Math episodes are closed loop, its replays ``paper``); ``lookahead``:
    the next boxes the policy was shown."""
    from robobpp.scoring.scores import ANCHORS_VERSION

    rows = list(results)
    return {
        **environment(),
        "physics": merged(r.physics_version for r in rows),
        "math_rules": merged(r.rules_version for r in rows),
        "sampler": merged(r.sampler_version for r in rows),
        "anchors": ANCHORS_VERSION,
        "protocol": protocol,
        "lookahead": lookahead,
        "split": split,
        "seed": seed,
        "groups": groups,
    }


def current_versions() -> dict[str, str]:
    """The versions this code produces (what a board shows): physics, Math rules, sampler, anchors."""
    from robobpp.datasets.sampling import SAMPLER_VERSION
    from robobpp.scoring.scores import ANCHORS_VERSION
    from robobpp.sim.math_pack import MATH_RULES_VERSION
    from robobpp.sim.physics.config import PHYSICS_VERSION

    return {
        "physics": PHYSICS_VERSION,
        "math_rules": MATH_RULES_VERSION,
        "sampler": SAMPLER_VERSION,
        "anchors": ANCHORS_VERSION,
    }


def recorded_rules() -> dict[str, str]:
    """The Math rules and sampler versions as a worker records them with a run of this code: what a board
    requires of a run (``robobpp.db.queries.current_rules``); a run without them ran version 1 of both."""
    versions = current_versions()
    return {"math_rules": versions["math_rules"], "sampler": versions["sampler"]}


def one_line(provenance: Mapping[str, Any]) -> str:
    """A provenance as one ``key value · ...`` line (tables' captions, Markdown and LaTeX footers)."""
    parts = []
    for key in FIELDS:
        value = provenance.get(key)
        if value is None:
            continue
        text = ",".join(map(str, value)) if isinstance(value, list) else str(value)
        if key in ("commit", "datasets_manifest_sha256") and len(text) > 12:
            text = text[:12] + ("-dirty" if text.endswith("-dirty") else "")  # the full value is in JSON
        parts.append(f"{key} {text}")
    return " · ".join(parts)
