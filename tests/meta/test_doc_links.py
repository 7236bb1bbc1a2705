"""Links between the docs resolve: every relative link in README.md, CONTRIBUTING.md, BENCHMARKS.md and docs/**/*.md
names a file of the repository and, with ``#anchor``, a heading of that page (GitHub's anchors: lower case,
punctuation dropped, spaces as hyphens, a repeated heading numbered)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PAGES = [
    ROOT / "README.md",
    ROOT / "CONTRIBUTING.md",
    ROOT / "BENCHMARKS.md",
    *sorted((ROOT / "docs").rglob("*.md")),
]
LINK = re.compile(r"\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def anchors(page: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", page.read_text()).splitlines():
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        slug = re.sub(r"[^\w\- ]", "", m.group(1).replace("`", "").lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def broken(page: Path) -> list[str]:
    out = []
    for target in LINK.findall(FENCE.sub("", page.read_text())):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists():
            out.append(f"{page.name}: {target} (no such file)")
        elif anchor and file.suffix == ".md" and anchor not in anchors(file):
            out.append(f"{page.name}: {target} (no such heading)")
    return out


def test_every_relative_link_resolves() -> None:
    problems = [p for page in PAGES for p in broken(page)]
    assert not problems, "\n".join(problems)


def test_anchors_follow_github(tmp_path: Path) -> None:
    page = tmp_path / "p.md"
    page.write_text(
        "# A `code` title: with (punctuation)!\n## Two protocols: closed loop and the paper's\n## X\n## X\n"
    )
    assert anchors(page) == {
        "a-code-title-with-punctuation",
        "two-protocols-closed-loop-and-the-papers",
        "x",
        "x-1",
    }
    page.write_text(page.read_text() + "[ok](#x-1) [bad](#y) [gone](nowhere.md)\n")
    assert broken(page) == ["p.md: #y (no such heading)", "p.md: nowhere.md (no such file)"]
