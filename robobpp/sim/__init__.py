"""Test settings: Math Pack (geometry), Physics Pack (PyBullet), Execution Pack (robot + OMPL).

``make_setting`` imports the physics stack only when a physical setting is asked for, so geometry-only
users never load pybullet.
"""

from __future__ import annotations

from typing import Any

from robobpp.core import FinalBox
from robobpp.extras import require
from robobpp.sim.base import Setting, StepOutcome
from robobpp.sim.math_pack import MATH_RULES_VERSION
from robobpp.vocabulary import SETTINGS  # re-exported: the settings make_setting knows

#: The packages each setting needs beyond the SDK, and the extra that brings them.
NEEDS: dict[str, tuple[tuple[str, ...], str, str]] = {
    "math": ((), "", "Math Pack"),
    "physics": (("pybullet",), "physics", "Physics Pack"),
    "execution": (("pybullet", "ompl"), "execution", "Execution Pack"),
}


def require_setting(name: str) -> None:
    """Raise :class:`~robobpp.extras.MissingExtraError` (naming the pip install) if ``name`` cannot run here."""
    packages, extra, title = NEEDS.get(name, ((), "", name))
    for package in packages:
        require(package, extra, title)


def make_setting(name: str, **options: Any) -> Setting:
    """A fresh setting instance by name (``math``, ``physics`` or ``execution``)."""
    if name == "math":
        from robobpp.sim.math_pack import MathPack

        return MathPack(**options)
    if name == "physics":
        require_setting(name)
        from robobpp.sim.physics import PhysicsPack

        return PhysicsPack(**options)
    if name == "execution":
        require_setting(name)
        from robobpp.sim.execution import ExecutionPack

        return ExecutionPack(**options)
    raise ValueError(f"unknown setting {name!r}; expected one of {', '.join(SETTINGS)}")


__all__ = [
    "MATH_RULES_VERSION",
    "SETTINGS",
    "FinalBox",
    "Setting",
    "StepOutcome",
    "make_setting",
    "require_setting",
]
