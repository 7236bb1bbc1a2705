"""Release → settle → measure → detect collapse: the placement procedure the Execution Pack reuses.

After a box is let go (by the Physics Pack's "hand" or by the robot's suction cup), :class:`Settler` steps
the world until everything is at rest or a cap, recording the largest linear and angular speeds over the
first ``stability_steps`` steps for Static Stability (docs/benchmark.md, "Metrics"). :func:`detect_collapse` then
compares every placed box with its own target.

Fast mode simulates only what can move. Every box starts frozen (static) except the released ones and the
column of boxes under their footprints (the load path). A simulated box moving faster than ``wake_speed``
wakes every frozen box whose bounds come within ``wake_margin_cm`` of its own, checked every step, so
nothing can reach a frozen box without waking it first (a box at 1 m/s travels 4 mm per step). The window
stops early once everything simulated has been at rest for ``rest_steps`` steps: by then the speeds that
Static Stability takes the maximum of are behind it. ``tests/sim/physics/test_fidelity.py`` holds this
against the full simulation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pybullet as p

from robobpp.core import box_label, static_stability
from robobpp.sim.physics.geometry import aabbs
from robobpp.sim.physics.recording import PoseRecorder
from robobpp.sim.physics.world import CM, PhysicsWorld, WorldBox


@dataclass(frozen=True, slots=True)
class SettleReport:
    """What one settle did: steps simulated, max speeds in the stability window, rest reached or not."""

    steps: int
    max_linear: float
    max_angular: float
    at_rest: bool
    simulated_boxes: int

    @property
    def static_stability(self) -> float:
        return static_stability(self.max_linear, self.max_angular)


@dataclass(frozen=True, slots=True)
class Displacement:
    """A box that moved too far from its own target (or fell off the pallet)."""

    index: int
    horizontal_cm: float
    fell: bool

    def describe(self, threshold_cm: float) -> str:
        """What happened to this box, against the collapse threshold, for a newcomer to read."""
        if self.fell:
            return f"{box_label(self.index)} fell off the pallet"
        return (
            f"{box_label(self.index)} moved {self.horizontal_cm:.1f} cm along x or y from where it was placed, "
            f"more than the collapse threshold of {threshold_cm:g} cm"
        )


class Settler:
    """Steps a world after a disturbance; in fast mode it freezes and wakes boxes as described above."""

    def __init__(self, world: PhysicsWorld) -> None:
        self.world = world
        self.config = world.config

    def _bounds(self, boxes: Sequence[WorldBox]) -> tuple[np.ndarray, np.ndarray]:
        centers, quats, halves = self.world.poses_cm(list(boxes))
        return aabbs(centers, quats, halves)

    def _near(
        self, lo: np.ndarray, hi: np.ndarray, olo: np.ndarray, ohi: np.ndarray, margin: float
    ) -> np.ndarray:
        """Mask over the ``olo/ohi`` boxes that come within ``margin`` (cm) of any of the ``lo/hi`` boxes."""
        if lo.shape[0] == 0 or olo.shape[0] == 0:
            return np.zeros(olo.shape[0], dtype=bool)
        sep = np.maximum(olo[None, :, :] - hi[:, None, :], lo[:, None, :] - ohi[None, :, :])
        near: np.ndarray = (sep.max(axis=2) <= margin).any(axis=0)
        return near

    def _column(self, seeds: Sequence[WorldBox], others: Sequence[WorldBox]) -> np.ndarray:
        """Mask over ``others`` lying under (or beside, within the margin) the seeds' footprints."""
        lo, hi = self._bounds(seeds)
        olo, ohi = self._bounds(others)
        if olo.shape[0] == 0:
            return np.zeros(0, dtype=bool)
        m = self.config.wake_margin_cm
        sep = np.maximum(olo[None, :, :2] - hi[:, None, :2], lo[:, None, :2] - ohi[None, :, :2]).max(axis=2)
        below = olo[None, :, 2] <= hi[:, None, 2] + m
        near: np.ndarray = ((sep <= m) & below).any(axis=0)
        return near

    def run(self, seeds: Sequence[WorldBox], recorder: PoseRecorder | None = None) -> SettleReport:
        """Simulate after the ``seeds`` were released; returns speeds and whether rest was reached.

        ``recorder`` (optional, for the replay) samples the simulated boxes' poses; it only reads them."""
        world, cfg = self.world, self.config
        fast = cfg.mode == "fast"
        if fast:
            seed_ids = {b.body for b in seeds}
            others = [b for b in world.boxes if b.body not in seed_ids]
            column = self._column(seeds, others)
            for box, near in zip(others, column, strict=True):
                (world.unfreeze if near else world.freeze)(box)
            for box in seeds:
                world.unfreeze(box)
        else:
            for box in world.boxes:
                world.unfreeze(box)
        active = [b for b in world.boxes if not b.frozen]
        reach = {b.body: math.sqrt(sum(h * h for h in b.half_extents_cm)) * CM for b in world.boxes}
        max_v = max_w = 0.0
        calm = 0
        steps = 0
        at_rest = False
        cid = world.client
        min_steps = 0 if fast else cfg.stability_steps
        if recorder is not None:
            recorder.sample(0, active)
        while steps < cfg.max_steps:
            p.stepSimulation(physicsClientId=cid)
            steps += 1
            if recorder is not None:
                recorder.sample(steps, active)
            step_v = step_w = 0.0
            moving: list[WorldBox] = []
            for box in active:
                (vx, vy, vz), (wx, wy, wz) = p.getBaseVelocity(box.body, physicsClientId=cid)
                v = math.sqrt(vx * vx + vy * vy + vz * vz)
                w = math.sqrt(wx * wx + wy * wy + wz * wz)
                step_v = max(step_v, v)
                step_w = max(step_w, w)
                if fast and v + w * reach[box.body] > cfg.wake_speed:
                    moving.append(box)
            if steps <= cfg.stability_steps:
                max_v, max_w = max(max_v, step_v), max(max_w, step_w)
            calm = calm + 1 if step_v < cfg.rest_linear and step_w < cfg.rest_angular else 0
            if moving:
                frozen = [b for b in world.boxes if b.frozen]
                if frozen:
                    lo, hi = self._bounds(moving)
                    flo, fhi = self._bounds(frozen)
                    for box, near in zip(
                        frozen, self._near(lo, hi, flo, fhi, cfg.wake_margin_cm), strict=True
                    ):
                        if near:
                            world.unfreeze(box)
                            active.append(box)
            if calm >= cfg.rest_steps and steps >= min_steps:
                at_rest = True
                break
        simulated = len(active)
        if recorder is not None:
            recorder.sample(steps, active, force=True)
        if fast:
            for box in world.boxes:
                world.freeze(box)
        return SettleReport(steps, max_v, max_w, at_rest, simulated)


def detect_collapse(
    world: PhysicsWorld,
    boxes: Sequence[WorldBox],
    targets_cm: np.ndarray,
    indices: Sequence[int],
    threshold_cm: float,
) -> list[Displacement]:
    """Boxes whose centre moved more than ``threshold_cm`` along x or y from its target, or fell off.

    "Fell off" means the centre left the pallet's footprint or sank below its deck (the box lies on the
    ground beside it).
    """
    if not boxes:
        return []
    centers, _, _ = world.poses_cm(list(boxes))
    container = world.container
    assert container is not None, "add_pallet() first"
    # The reference implementation's rule: |dx| or |dy| over the threshold (not the Euclidean distance).
    horizontal = np.abs(centers[:, :2] - np.asarray(targets_cm)[:, :2]).max(axis=1)
    outside = (centers[:, 0] < 0) | (centers[:, 0] > container.length)
    outside |= (centers[:, 1] < 0) | (centers[:, 1] > container.width) | (centers[:, 2] < 0)
    return [
        Displacement(int(i), float(d), bool(f))
        for i, d, f in zip(indices, horizontal, outside, strict=True)
        if f or d > threshold_cm
    ]
