"""Box poses over time for the replay: what moved during one step, sampled compactly.

The Physics Pack's trace already holds every box's pose *after* each step (``extra["poses"]``); this
adds how the boxes got there — a box settling after its release, a pile collapsing, a neighbour the
robot's arm shoved — so the replay can show it happening. Only reads poses: recording never changes
what is simulated.

A :class:`PoseRecorder` is handed to the code that steps the world (the settle, the Execution Pack's
drive). It samples the boxes it is shown every ``every`` simulation steps, and :meth:`take` returns the
step's *track*, stored in ``extra["track"]``::

    {"tick_s": dt, "t": [tick, ...],       # sample times from the start of the step, in world ticks
     "boxes": [[index, first, x, y, z, qx, qy, qz, qw, x, y, ...], ...]}

Per box: its index (= placement order), the first sample it appears in, then 7 integers per sample
from there on — the centre in mm (container frame) and the attitude quaternion × 10⁴. A box is kept only
from just before its first move to its last, and only if it strays visibly (:data:`VISIBLE_MM`,
:data:`VISIBLE_QUAT`) from where the step leaves it; otherwise it is drawn at its step poses.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from robobpp.sim.physics.world import PhysicsWorld, WorldBox

#: Quantisation of the recorded poses: centres in mm, quaternion components in 10⁻⁴.
TRACK_POS_PER_CM = 10
TRACK_QUAT_SCALE = 10_000
#: Default sampling: every 8th step of the 240 Hz world = 30 samples per simulated second.
TRACK_EVERY = 8
#: A box is tracked when it strays further than this from where the step leaves it: 3 mm, or a quaternion
#: component 0.003 (about 0.3°). Less is invisible at the scale of the cell.
VISIBLE_MM = 3
VISIBLE_QUAT = 30


class PoseRecorder:
    """Samples the poses of the boxes being simulated during one step (see the module docstring)."""

    def __init__(self, world: PhysicsWorld, every: int = TRACK_EVERY) -> None:
        if every < 1:
            raise ValueError("the recorder samples every >= 1 steps")
        self.world = world
        self.every = every
        self._t0 = 0
        self._times: list[int] = []
        #: body id -> (first sample number, [quantised pose per sample from then on])
        self._poses: dict[int, tuple[int, list[np.ndarray]]] = {}

    def begin(self, t0: int) -> None:
        """A stretch of simulation (a settle, a drive) starts ``t0`` world ticks into the step."""
        self._t0 = t0

    def sample(self, k: int, boxes: Sequence[WorldBox], *, force: bool = False) -> None:
        """After ``k`` steps of the current stretch: record ``boxes`` if ``k`` is on the sampling grid."""
        if not force and k % self.every:
            return
        t = self._t0 + k
        if self._times and t < self._times[-1]:
            return
        # The same time again (a forced last sample on the grid; a settle starting where the drive ended):
        # the boxes already sampled then keep their pose, the others join that sample.
        if not self._times or t > self._times[-1]:
            self._times.append(t)
        n = len(self._times) - 1
        todo = [b for b in boxes if (row := self._poses.get(b.body)) is None or row[0] + len(row[1]) <= n]
        if not todo:
            return
        centers, quats, _ = self.world.poses_cm(todo)
        q = np.concatenate([np.round(centers * TRACK_POS_PER_CM), np.round(quats * TRACK_QUAT_SCALE)], axis=1)
        for box, pose in zip(todo, q.astype(np.int64), strict=True):
            first, rows = self._poses.setdefault(box.body, (n, []))
            # A box that left the simulated set and came back: hold its pose over the gap.
            while first + len(rows) < n:
                rows.append(rows[-1])
            rows.append(pose)

    def discard(self) -> None:
        """Forget what was sampled (a step that ended before its settle) and start again at t = 0."""
        self._times, self._poses, self._t0 = [], {}, 0

    def take(self, boxes: Sequence[WorldBox]) -> dict[str, Any] | None:
        """The step's track (``boxes`` in placement order give the indices) and a fresh start; None when
        nothing visibly moved."""
        index = {b.body: i for i, b in enumerate(boxes)}
        out = []
        for body, (first, rows) in self._poses.items():
            if body not in index:
                continue
            track = np.stack(rows)
            # Samples where the box stands still add nothing: before its first move it stands where the
            # last step left it, after its last move where this step leaves it (the step's poses).
            moving = np.flatnonzero(np.abs(np.diff(track, axis=0)).max(axis=1) > 1)
            if len(moving) == 0 or not _visible(track):
                continue
            start, stop = int(moving[0]), int(moving[-1]) + 2
            out.append([index[body], first + start, *track[start:stop].reshape(-1).tolist()])
        times = list(self._times)
        self.discard()
        if not out:
            return None
        out.sort(key=lambda row: row[0])
        return {"tick_s": self.world.config.dt, "t": times, "boxes": out}


def _visible(track: np.ndarray) -> bool:
    """Whether a box's samples leave its final pose by more than :data:`VISIBLE_MM` or :data:`VISIBLE_QUAT`."""
    spread = np.abs(track - track[-1]).max(axis=0)
    return bool(spread[:3].max() > VISIBLE_MM or spread[3:].max() > VISIBLE_QUAT)
