"""Pure-numpy geometry of the packing problem: boxes, container state, heightmap, feasibility.

Nothing here imports pybullet or the web stack; every other layer builds on it.
"""

from robobpp.core.box import ORIENTATIONS, Box, ContainerSpec, Placement, box_label, oriented_dims
from robobpp.core.container import ContainerState
from robobpp.core.episode_spec import EpisodeSpec
from robobpp.core.feasibility import Infeasible, SupportModel, check_action, check_support, is_supported
from robobpp.core.heightmap import drop_height_map, footprint_cells
from robobpp.core.observation import Action, EpisodeInfo, Observation
from robobpp.core.readings import FinalBox, static_stability

__all__ = [
    "ORIENTATIONS",
    "Action",
    "Box",
    "ContainerSpec",
    "ContainerState",
    "EpisodeInfo",
    "EpisodeSpec",
    "FinalBox",
    "Infeasible",
    "Observation",
    "Placement",
    "SupportModel",
    "check_action",
    "box_label",
    "check_support",
    "drop_height_map",
    "footprint_cells",
    "is_supported",
    "oriented_dims",
    "static_stability",
]
