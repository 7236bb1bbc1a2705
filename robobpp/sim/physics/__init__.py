"""Physics Pack: a PyBullet world (DIRECT) with the pallet and box primitives, settling and collapse.

``PhysicsWorld`` and ``Settler``/``detect_collapse`` are the reusable parts the Execution Pack builds on;
``PhysicsPack`` is the setting the episode loop drives. The names load lazily, so
``robobpp.sim.physics.config`` (``PHYSICS_VERSION``, which the server's board queries read) is importable
without loading pybullet.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from robobpp.sim.physics.config import PHYSICS_VERSION, PhysicsConfig

if TYPE_CHECKING:
    from robobpp.sim.physics.pack import PhysicsPack
    from robobpp.sim.physics.reward import stability_reward
    from robobpp.sim.physics.settle import Displacement, Settler, SettleReport, detect_collapse
    from robobpp.sim.physics.world import PhysicsWorld, WorldBox

_LAZY = {
    "PhysicsPack": "pack",
    "stability_reward": "reward",
    "Displacement": "settle",
    "Settler": "settle",
    "SettleReport": "settle",
    "detect_collapse": "settle",
    "PhysicsWorld": "world",
    "WorldBox": "world",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)


__all__ = [
    "PHYSICS_VERSION",
    "Displacement",
    "PhysicsConfig",
    "PhysicsPack",
    "PhysicsWorld",
    "SettleReport",
    "Settler",
    "WorldBox",
    "detect_collapse",
    "stability_reward",
]
