"""Every third-party module the tests (and bench scripts) import is declared in pyproject.toml.

A test that imports a package no extra declares passes on a developer's machine where it happens to be installed
and fails on a fresh one (this is how ``jsonschema`` went missing). This check reads the imports with ``ast`` and
maps each top-level module to the distribution that provides it.
"""

from __future__ import annotations

import ast
import sys
import tomllib
from importlib.metadata import packages_distributions
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[2]
SCANNED = ("tests", "bench", "examples")
OWN = {"robobpp", "tests", "bench", "deploy", "_common", "conftest"}
#: Modules a script imports only when run by another interpreter, never robobpp's: bench/reference_replay.py's
#: ``run`` step executes the reference simulator's own package in a virtual environment of its own.
FOREIGN = {"packsim"}
#: Modules a bench script uses only when they are installed by hand, and skips with a note otherwise: no extra
#: declares them. bench/bench_env_speed.py times Jumanji's BinPack beside the Gym env.
BY_HAND = {"jax", "jumanji"}


def declared_distributions() -> set[str]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = list(project["dependencies"])
    for extra in project.get("optional-dependencies", {}).values():
        requirements += extra
    names: set[str] = set()
    for line in requirements:
        req = Requirement(line)
        if canonicalize_name(req.name) != "robobpp":  # an extra that pulls in other extras
            names.add(canonicalize_name(req.name))
    return names


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
    return found


def test_every_imported_module_is_declared() -> None:
    declared = declared_distributions()
    providers = packages_distributions()
    missing: dict[str, set[str]] = {}
    for folder in SCANNED:
        for path in sorted((ROOT / folder).rglob("*.py")):
            local = {p.stem for p in path.parent.glob("*.py")}
            for module in (
                imported_modules(path) - OWN - FOREIGN - BY_HAND - local - set(sys.stdlib_module_names)
            ):
                dists = {canonicalize_name(d) for d in providers.get(module, [])}
                if not dists & declared:
                    missing.setdefault(module, set()).add(str(path.relative_to(ROOT)))
    assert not missing, "imported but declared in no extra of pyproject.toml: " + "; ".join(
        f"{module} ({', '.join(sorted(files))})" for module, files in sorted(missing.items())
    )


def test_the_check_sees_an_undeclared_import(tmp_path: Path) -> None:
    """The scanner is not vacuous: an import of a package nobody declares is reported."""
    probe = tmp_path / "probe.py"
    probe.write_text("import jsonschema\nfrom robobpp import core\nimport os\n")
    assert imported_modules(probe) == {"jsonschema", "robobpp", "os"}
    assert "pytest" in declared_distributions()
