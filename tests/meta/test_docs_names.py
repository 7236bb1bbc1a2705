"""Names the docs cite point at real code and real sections.

- every dotted name in backticks that starts with ``robobpp.`` (``robobpp.scoring.scores.EQUAL_DECIMALS``) imports:
  the longest importable module, then attributes one by one (a dataclass or model field counts);
- every repository path the docs name (``robobpp/.../x.py``, ``bench/x.py``, ``tests/...``, ``examples/...``)
  exists;
- every section cited by name (``docs/physics.md, "Fidelity"``, ``BENCHMARKS.md, "Board updates"``), in the docs
  and in the code, starts a heading or a bold paragraph lead of that page, and every ``docs/x.md#anchor`` written
  in the code is a heading of that page.

Relative markdown links between the pages (docs/ and its subfolders included) are checked by test_doc_links.py."""

from __future__ import annotations

import dataclasses
import importlib
import re
import subprocess
from functools import cache
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from tests.meta.test_doc_links import PAGES, ROOT, anchors

# A name, not a pattern of names such as `robobpp.pull.<hash>`, nor a part of another (a label `org.robobpp.build`).
DOTTED = re.compile(r"`[^`\n]*?(?<![.\w])(robobpp(?:\.[A-Za-z_]\w*+)++)(?!\.<)[^`\n]*`")
# A file (with its extension) or a folder (with its slash): not `robobpp/1` (the protocol) nor `robobpp/Pack-v0`.
PATH = re.compile(r"(?<![\w./-])((?:robobpp|bench|tests|examples|migrations)/[\w./-]*(?:\.[a-z]{2,4}\b|/))")
# A page, then a section name in quotes: `docs/x.md, "Name"`, `BENCHMARKS.md ("Name")`, `[x.md](x.md), "Name"`.
PAGE = r"((?:docs/)?(?:validation/)?[\w-]+\.md|BENCHMARKS\.md|README\.md|CONTRIBUTING\.md)"
# The name starts as a heading does (a capital or a backtick) and holds no code punctuation.
CITED = re.compile(PAGE + r"`*\)?,?\s*\(?\s*(?:section\s+)?\"([A-Z`][^\"(){}\[\]=<>]{1,119})\"")
CODE_ANCHOR = re.compile(r"\b(docs/[\w/-]+\.md)#([\w-]+)")
SOURCES = ("robobpp", "tests", "bench", "migrations", "examples")


def _rel(page: Path) -> str:
    return str(page.relative_to(ROOT)) if page.is_relative_to(ROOT) else str(page)


@cache
def _module(name: str) -> ModuleType | None:
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as e:
        if e.name and name.startswith(e.name):
            return None
        raise


def _has(obj: Any, attr: str) -> tuple[bool, Any]:
    if hasattr(obj, attr):
        return True, getattr(obj, attr)
    fields = {**getattr(obj, "__annotations__", {}), **getattr(obj, "model_fields", {})}
    if dataclasses.is_dataclass(obj):
        fields.update({f.name: f for f in dataclasses.fields(obj)})
    return attr in fields, None


def resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        module = _module(".".join(parts[:cut]))
        if module is None:
            continue
        obj: Any = module
        for attr in parts[cut:]:
            found, obj = _has(obj, attr)
            if not found:
                return False
            if obj is None:  # a field without a class attribute: nothing further to follow
                return attr == parts[-1]
        return True
    return False


def _text(page: Path) -> str:
    return re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M)


def _targets(page: Path) -> list[str]:
    """Headings and bold paragraph leads of a page, lower case, without backticks."""
    text = _text(page)
    found = [m.group(1) for m in re.finditer(r"^#{1,6}\s+(.*?)\s*$", text, re.M)]
    found += [m.group(1) for m in re.finditer(r"^(?:- )?\*\*(.+?)\*\*", text, re.M)]
    return [re.sub(r"\s+", " ", t.replace("`", "")).lower() for t in found]


def _page(name: str, citing: Path) -> Path | None:
    for candidate in (ROOT / name, citing.parent / name, ROOT / "docs" / name):
        if candidate.is_file():
            return candidate
    return None


def _flat(text: str) -> str:
    """Text with comment continuations joined: `"Static\\n    #: Stability"` reads as one phrase."""
    return re.sub(r"\n\s*(?:#:?|\*|//)?\s*", " ", text)


def _sources() -> list[Path]:
    listed = subprocess.run(["git", "ls-files", *SOURCES], cwd=ROOT, capture_output=True, text=True)
    if listed.returncode == 0:
        names = listed.stdout.split()
        found = [ROOT / n for n in names if n.endswith((".py", ".html", ".toml")) and (ROOT / n).is_file()]
    else:
        found = [p for s in SOURCES for p in (ROOT / s).rglob("*.py")]
    return [p for p in found if p != Path(__file__).resolve()]  # this file's examples are not citations


def cited_sections(path: Path) -> list[str]:
    out = []
    for page_name, name in CITED.findall(_flat(path.read_text(errors="replace"))):
        page = _page(page_name, path)
        if page is None:
            out.append(f'{_rel(path)}: {page_name} (no such page), "{name}"')
            continue
        wanted = re.sub(r"\s+", " ", name.replace("`", "")).strip().lower()
        if not any(t.startswith(wanted) for t in _targets(page)):
            out.append(f'{_rel(path)}: {page_name}, "{name}" (no heading starts so)')
    return out


def test_dotted_names_in_the_docs_exist() -> None:
    missing = sorted(
        {f"{_rel(p)}: {name}" for p in PAGES for name in DOTTED.findall(_text(p)) if not resolves(name)}
    )
    assert not missing, "\n".join(missing)


def test_paths_in_the_docs_exist() -> None:
    missing = []
    for page in PAGES:
        for path in PATH.findall(page.read_text()):
            path = path.rstrip(".")
            if not (ROOT / path).exists() and "*" not in path:
                missing.append(f"{_rel(page)}: {path}")
    assert not missing, "\n".join(sorted(set(missing)))


def test_sections_cited_by_name_exist() -> None:
    problems = [p for path in PAGES + _sources() for p in cited_sections(path)]
    assert not problems, "\n".join(sorted(set(problems)))


def test_anchors_written_in_the_code_exist() -> None:
    problems = []
    for path in _sources():
        for page, anchor in CODE_ANCHOR.findall(path.read_text(errors="replace")):
            if not (ROOT / page).is_file():
                problems.append(f"{_rel(path)}: {page} (no such page)")
            elif anchor not in anchors(ROOT / page):
                problems.append(f"{_rel(path)}: {page}#{anchor} (no such heading)")
    assert not problems, "\n".join(sorted(set(problems)))


@pytest.mark.parametrize(
    ("name", "exists"),
    [
        ("robobpp.scoring.scores.EQUAL_DECIMALS", True),
        ("robobpp.sim.physics.PhysicsConfig.friction_anchor", True),
        ("robobpp.scoring.metrics.static_stability", False),
        ("robobpp.no_such_module", False),
    ],
)
def test_the_name_check_tells_real_from_stale(name: str, exists: bool) -> None:
    assert resolves(name) is exists


def test_the_section_check_reads_citations(tmp_path: Path) -> None:
    page = tmp_path / "p.md"
    page.write_text("# P\n## Fidelity\n**How it counts** (text)\n")
    code = tmp_path / "c.py"
    code.write_text(f'"""See {page}, "Fidelity"; {page}, "How it\n    counts"; {page}, "Creep"."""\n')
    problems = cited_sections(code)
    assert len(problems) == 1 and '"Creep"' in problems[0]
