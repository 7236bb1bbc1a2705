"""Physics Pack: a PyBullet world (DIRECT) with the pallet and box primitives, settling and collapse.

``PhysicsWorld`` and ``Settler``/``detect_collapse`` are the reusable parts the Execution Pack builds on;
``PhysicsPack`` is the setting the episode loop drives.
"""

from robobpp.sim.physics.config import PhysicsConfig
from robobpp.sim.physics.pack import PhysicsPack
from robobpp.sim.physics.reward import stability_reward
from robobpp.sim.physics.settle import Displacement, Settler, SettleReport, detect_collapse
from robobpp.sim.physics.world import PhysicsWorld, WorldBox

__all__ = [
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
