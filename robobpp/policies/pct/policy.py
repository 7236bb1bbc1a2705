"""The ``pct`` policy: the authors' trained PCT network choosing among EMS leaf nodes, greedily."""

from __future__ import annotations

import zlib

import numpy as np

from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.policies.base import BasePolicy
from robobpp.policies.pct.checkpoint import load_weights
from robobpp.policies.pct.leaves import SpaceTracker, build_nodes
from robobpp.policies.pct.network import PCTNetwork, PCTOutput

_NETWORK: PCTNetwork | None = None


def network() -> PCTNetwork:
    """The network over the cached, verified weights (built once per process)."""
    global _NETWORK
    if _NETWORK is None:
        _NETWORK = PCTNetwork(load_weights())
    return _NETWORK


class PCT(BasePolicy):
    """PCT (Zhao et al., ICLR 2022) with the weights the RoboBPP authors trained on Repetitive.

    Each decision builds the packing configuration tree's nodes (``leaves.py``), runs the network
    (``network.py``) and places the box at the most probable feasible leaf. ``None`` when no leaf is
    feasible. Deterministic: the leaf shuffle is seeded by ``seed`` and the episode id.
    """

    name = "pct"

    def __init__(self, seed: int = 0) -> None:
        self.seed = seed
        self.net = network()
        self._tracker: SpaceTracker | None = None
        self._rng = np.random.default_rng(seed)
        self.last: PCTOutput | None = None

    def reset(self, info: EpisodeInfo) -> None:
        c = info.container
        self._tracker = SpaceTracker(c.length, c.width, c.height)
        self._rng = np.random.default_rng([self.seed, zlib.crc32(info.episode_id.encode())])

    def act(self, obs: Observation) -> Action | None:
        c = obs.container
        if self._tracker is None:  # act without reset (a bare caller): start from this container
            self._tracker = SpaceTracker(c.length, c.width, c.height)
        spaces = self._tracker.sync(obs.placed)
        nodes = build_nodes(obs, spaces, self._rng)
        if not nodes.actions:
            self.last = None
            return None
        out = self.net(
            nodes.internal,
            nodes.leaves,
            nodes.next_item,
            nodes.internal_valid,
            nodes.leaf_valid,
            1.0 / max(c.length, c.width, c.height),
        )
        self.last = out
        x, y, orientation = nodes.actions[out.choice]
        return Action(float(x), float(y), orientation)
