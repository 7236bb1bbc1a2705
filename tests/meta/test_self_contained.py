"""Committed text cites only what the repository holds: no project notes kept outside it (the benchmark
specification, the design notes, the notes on the reference package, the paper's source) and no path of a
particular machine. The rules a user needs live in docs/ (docs/benchmark.md first) and are cited from there."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TEXT = (".py", ".md", ".html", ".js", ".css", ".cff", ".toml", ".yml", ".yaml", ".txt", ".cfg", ".ini", ".sh")
# Built from pieces so that this file does not match itself.
OUTSIDE = re.compile(
    r"\b"
    + "BENCHMARK"
    + r"\.md\b|\b"
    + "DESIGN"
    + r"\.md\b|packsim-"
    + "facts|robobpp-paper"
    + r"\.tex"
    + "|/"
    + "work/|/"
    + "root/"
)


def test_no_citation_of_files_outside_the_repository() -> None:
    listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True)
    if listed.returncode != 0:
        pytest.skip("not a git checkout: the committed files are unknown")
    files = listed.stdout
    found = []
    for name in files.splitlines():
        path = ROOT / name
        if not name.endswith(TEXT) or not path.is_file():
            continue
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if OUTSIDE.search(line):
                found.append(f"{name}:{number}: {line.strip()[:120]}")
    assert not found, "cite docs/ instead:\n" + "\n".join(found)


def test_the_check_catches_a_citation() -> None:
    assert OUTSIDE.search("the rule (" + "BENCHMARK" + ".md §3)")
    assert not OUTSIDE.search("figures in BENCHMARKS.md and docs/benchmark.md")
