"""requirements/ci.txt (the lock CI installs from) agrees with the ranges in pyproject.toml.

A dependency added to pyproject.toml without refreshing the lock would be installed unpinned in CI, or not at all
when its range excludes the locked version; either way CI would stop being reproducible. Refresh command:
CONTRIBUTING.md.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[2]


def locked_versions(text: str) -> dict[str, str]:
    pins: dict[str, str] = {}
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if "==" in line and not line.startswith("-"):
            name, version = line.split("==", 1)
            pins[canonicalize_name(name.split("[")[0])] = version.split(";")[0].strip()
    return pins


def declared_requirements() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    lines = list(project["dependencies"])
    for extra in project.get("optional-dependencies", {}).values():
        lines += extra
    return [r for r in map(Requirement, lines) if canonicalize_name(r.name) != "robobpp"]


def lock_problems(requirements: list[Requirement], pins: dict[str, str]) -> list[str]:
    problems = []
    for req in requirements:
        if req.marker is not None and not req.marker.evaluate({"extra": ""}):
            continue  # a requirement for another platform or Python
        version = pins.get(canonicalize_name(req.name))
        if version is None:
            problems.append(f"{req.name} is not in the lock")
        elif not req.specifier.contains(version, prereleases=True):
            problems.append(f"{req.name}: locked {version} is outside {req.specifier}")
    return problems


def test_lock_covers_every_declared_requirement() -> None:
    pins = locked_versions((ROOT / "requirements" / "ci.txt").read_text())
    assert not lock_problems(declared_requirements(), pins)


def test_lock_check_reports_a_stale_pin() -> None:
    stale = {"numpy": "1.20.0"}
    assert lock_problems([Requirement("numpy>=1.26"), Requirement("httpx>=0.27")], stale) == [
        "numpy: locked 1.20.0 is outside >=1.26",
        "httpx is not in the lock",
    ]
