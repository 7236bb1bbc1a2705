"""CITATION.cff: a valid Citation File Format 1.2.0 file for the software at its current version, with the
RoboBPP paper it implements among its references; docs/reporting.md's BibTeX says the same."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import yaml

import robobpp

ROOT = Path(__file__).resolve().parents[2]


def _cff() -> dict:
    return yaml.safe_load((ROOT / "CITATION.cff").read_text())


def test_citation_file_has_the_required_fields_and_the_current_version() -> None:
    cff = _cff()
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    for key in ("message", "title", "authors"):  # required by the format
        assert cff.get(key), key
    assert all("name" in a or "family-names" in a for a in cff["authors"])
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert cff["version"] == version == robobpp.__version__  # a release bumps all three together
    assert cff["license"] == "MIT" and "MIT License" in (ROOT / "LICENSE").read_text()


def test_the_paper_is_referenced_with_its_authors() -> None:
    (paper,) = [r for r in _cff()["references"] if r["type"] == "article"]
    assert paper["title"] == "RoboBPP: Benchmarking Robotic Online Bin Packing with Physics-based Simulation"
    assert paper["year"] == 2025 and len(paper["authors"]) == 11
    assert [a["family-names"] for a in paper["authors"][:3]] == ["Wang", "Zhao", "Xu"]
    assert all(a.get("given-names") for a in paper["authors"])
    # The BibTeX in docs/reporting.md names the same authors in the same order, and the same version.
    reporting = (ROOT / "docs" / "reporting.md").read_text()
    match = re.search(r"@article\{wang2025robobpp,.*?author\s*=\s*\{(.*?)\},\n", reporting, re.S)
    assert match is not None, "no BibTeX entry wang2025robobpp in docs/reporting.md"
    bib = match.group(1)
    names = [n.strip() for n in bib.replace("\n", " ").split(" and ")]
    assert names == [f"{a['family-names']}, {a['given-names']}" for a in paper["authors"]]
    assert f"version = {{{robobpp.__version__}}}" in reporting.replace("  ", " ")
