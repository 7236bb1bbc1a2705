"""The hash of everything that goes into the robobpp:debian image, so a test can tell a stale image.

deploy/build-images.sh stores it as the image label ``org.robobpp.source``; tests/deploy/ compares it with the
working tree's. Standard library only: the build script runs it with the host's Debian Python.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: What deploy/Dockerfile.debian copies or installs from (the pinned versions of the wheels included).
INPUTS = ("pyproject.toml", "setup.py", "README.md", "alembic.ini", "requirements/ci.txt",
          "deploy/Dockerfile.debian", "robobpp", "migrations")  # fmt: skip
SKIPPED = ("__pycache__", ".egg-info")


def source_hash(root: Path = ROOT) -> str:
    digest = hashlib.sha256()
    for name in INPUTS:
        top = root / name
        files = [top] if top.is_file() else sorted(p for p in top.rglob("*") if p.is_file())
        for path in files:
            rel = path.relative_to(root).as_posix()
            if any(part.endswith(SKIPPED) for part in rel.split("/")) or rel.endswith(
                (".pyc", ".pyo", ".so")
            ):
                continue
            digest.update(rel.encode() + b"\0" + hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()[:16]


if __name__ == "__main__":
    sys.stdout.write(source_hash() + "\n")
