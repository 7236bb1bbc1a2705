"""Test settings: Math Pack (geometry), Physics Pack (PyBullet), Execution Pack (robot + OMPL).

``make_setting`` imports the physics stack only when a physical setting is asked for, so geometry-only
users never load pybullet.
"""

from __future__ import annotations

from robobpp.sim.base import FinalBox, Setting, StepOutcome

SETTINGS: tuple[str, ...] = ("math", "physics", "execution")


def make_setting(name: str, **options: object) -> Setting:
    """A fresh setting instance by name (``math``, ``physics`` or ``execution``)."""
    if name == "math":
        from robobpp.sim.math_pack import MathPack

        return MathPack(**options)  # type: ignore[arg-type]
    if name == "physics":
        from robobpp.sim.physics import PhysicsPack  # type: ignore[attr-defined]

        return PhysicsPack(**options)
    if name == "execution":
        from robobpp.sim.execution import ExecutionPack  # type: ignore[attr-defined]

        return ExecutionPack(**options)
    raise ValueError(f"unknown setting {name!r}; expected one of {', '.join(SETTINGS)}")


__all__ = ["SETTINGS", "FinalBox", "Setting", "StepOutcome", "make_setting"]
