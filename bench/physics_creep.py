"""Is the full simulation's creep physics or a solver artefact? (docs/validation/physics.md, "Creep").

One real episode's actions are recorded once (the default physics, a grid policy), then replayed box by box
in the *full* simulation (every box dynamic, ≥ 200 steps per placement, then until at rest) under numerical
variants at the same simulated time: a smaller time step (the step counts scaled so the stability window,
the rest test and the cap stay the same seconds), more solver iterations, and the contact options PyBullet
offers against resting drift (friction anchors, pyramid instead of cone friction, split impulse off).
Every variant but the anchored ones runs without friction anchors, i.e. with physics version 2's contacts.
Only the physics varies; the boxes, the actions and the release procedure are the same.

Figures per variant:

* ``far drift``: per placement, the mean horizontal displacement of the boxes already placed that lie more
  than ``wake_margin_cm`` (10 cm) from the new box's footprint, i.e. that the new box cannot touch and
  fast mode keeps frozen; the median and the mean over placements (µm).
* ``box 0``: how far the first box (on the deck, under the pile) moved horizontally over the replay (mm).
* ``LS``: Local Stability at the end of the replay (mean 3-D distance planned → actual, mm).
* ``rest drift``: after the replay, the finished pile simulated for 2 s with nothing added; the mean
  horizontal displacement of every box over that time (µm). A pile of boxes with friction 1 at rest does
  not move, so anything here is the solver's.
* ``CPU s``: process time of the replay.

    python bench/physics_creep.py --dataset repetitive --group 0 --policy dbl --boxes 40
    python bench/physics_creep.py --variants base,anchor --boxes 80   # a subset, a longer replay
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pybullet as p

from robobpp.core import Action, Infeasible
from robobpp.datasets import episode_specs
from robobpp.episode import run_episode
from robobpp.policies import load_policy
from robobpp.sim.physics import PhysicsConfig, PhysicsPack
from robobpp.sim.physics.world import PhysicsWorld

#: name → (PhysicsConfig changes, time-step divisor, engine parameters). Every variant but the anchored ones
#: runs without friction anchors (physics version 2's contacts); "anchor" is version 3's default.
OFF = {"friction_anchor": False}
VARIANTS: dict[str, tuple[dict[str, Any], int, dict[str, Any]]] = {
    "base": (OFF, 1, {}),
    "dt/2": (OFF, 2, {}),
    "dt/4": (OFF, 4, {}),
    "dt/8": (OFF, 8, {}),
    "dt/16": (OFF, 16, {}),
    "iter200": ({**OFF, "solver_iterations": 200}, 1, {}),
    "iter1000": ({**OFF, "solver_iterations": 1000}, 1, {}),
    "iter200 dt/4": ({**OFF, "solver_iterations": 200}, 4, {}),
    "iter1000 dt/4": ({**OFF, "solver_iterations": 1000}, 4, {}),
    "pyramid": (OFF, 1, {"enableConeFriction": 0}),
    "cone": (OFF, 1, {"enableConeFriction": 1}),
    "nosplit": (OFF, 1, {"useSplitImpulse": 0}),
    "anchor": ({"friction_anchor": True}, 1, {}),
    "anchor dt/4": ({"friction_anchor": True}, 4, {}),
    "anchor iter200": ({"friction_anchor": True, "solver_iterations": 200}, 1, {}),
}


def config_for(base: PhysicsConfig, changes: dict[str, Any], divisor: int) -> PhysicsConfig:
    """Full mode with ``changes``, the time step divided by ``divisor`` and every step count scaled by it."""
    return replace(
        base,
        mode="full",
        dt=base.dt / divisor,
        stability_steps=base.stability_steps * divisor,
        rest_steps=base.rest_steps * divisor,
        max_steps=base.max_steps * divisor,
        **changes,
    )


def record_actions(spec: Any, policy: str) -> list[Action]:
    result = run_episode(spec, load_policy(policy), PhysicsPack())
    print(
        f"# recorded in the default physics: {result.termination} after {result.boxes_placed} boxes: "
        f"{result.termination_detail}",
        flush=True,
    )
    return [
        Action(s.action["x"], s.action["y"], int(s.action["orientation"])) for s in result.steps if s.action
    ]


def replay(spec: Any, actions: list[Action], name: str, boxes: int) -> dict[str, Any]:
    changes, divisor, engine = VARIANTS[name]
    cfg = config_for(PhysicsConfig(), changes, divisor)
    pack = PhysicsPack(cfg)
    pack.record_tracks = False
    pack.reset(spec)
    world = pack.world
    assert world is not None
    if engine:
        p.setPhysicsEngineParameter(**engine, physicsClientId=world.client)
    margin = cfg.wake_margin_cm
    far_drift: list[float] = []
    collapse_at = None
    detail = ""
    start = time.process_time()
    for index, action in enumerate(actions[:boxes]):
        box = spec.boxes[index]
        before = world.poses_cm(list(pack.boxes))[0]
        outcome = pack.apply(box, action, index)
        if isinstance(outcome.termination, Infeasible) and outcome.placement is None:
            break  # too_high: the replay ends where the recorded episode could not go on
        after = world.poses_cm(list(pack.boxes))[0][: len(before)]
        if len(before):
            pl = outcome.placement
            assert pl is not None
            # horizontal separation of each old box's centre region from the new footprint (approximate:
            # centre distance minus half the box's footprint diagonal)
            halves = np.array([b.half_extents_cm for b in pack.boxes[: len(before)]])
            dx = np.maximum(0, np.abs(before[:, 0] - (pl.x + pl.length / 2)) - pl.length / 2 - halves[:, 0])
            dy = np.maximum(0, np.abs(before[:, 1] - (pl.y + pl.width / 2)) - pl.width / 2 - halves[:, 1])
            far = np.maximum(dx, dy) > margin
            moved = np.linalg.norm(after[:, :2] - before[:, :2], axis=1) * 1e4  # µm
            if far.any():
                far_drift.append(float(moved[far].mean()))
        if outcome.collapsed:
            collapse_at = index
            detail = outcome.termination.detail if outcome.termination else ""
            break
    cpu = time.process_time() - start
    placed = len(pack.boxes)
    centers = world.poses_cm(list(pack.boxes))[0]
    targets = np.array([pl.center for pl in pack.planned])
    ls_mm = float(np.linalg.norm(centers - targets, axis=1).mean() * 10)
    box0_mm = float(np.linalg.norm(centers[0, :2] - targets[0, :2]) * 10)
    rest_drift = rest_creep(world, cfg, seconds=2.0)
    return {
        "variant": name,
        "placed": placed,
        "collapse_at": collapse_at,
        "far_drift_median_um": float(np.median(far_drift)) if far_drift else None,
        "far_drift_mean_um": float(np.mean(far_drift)) if far_drift else None,
        "box0_mm": box0_mm,
        "ls_mm": ls_mm,
        "rest_drift_um": rest_drift,
        "cpu_s": cpu,
        "collapse": detail,
    }


def rest_creep(world: PhysicsWorld, cfg: PhysicsConfig, seconds: float) -> float:
    """Mean horizontal displacement (µm) of every box while the finished pile is simulated for ``seconds``."""
    for box in world.boxes:
        world.unfreeze(box)
    before = world.poses_cm()[0]
    world.step(round(seconds / cfg.dt))
    after = world.poses_cm()[0]
    return float(np.linalg.norm(after[:, :2] - before[:, :2], axis=1).mean() * 1e4)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--dataset", default="repetitive")
    parser.add_argument("--group", type=int, default=0)
    parser.add_argument("--policy", default="dbl")
    parser.add_argument("--boxes", type=int, default=40, help="replay at most this many placements")
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--out", type=Path, help="append one JSON line per variant")
    args = parser.parse_args()
    spec = episode_specs(args.dataset, groups=args.group + 1)[args.group]
    actions = record_actions(spec, args.policy)
    print(
        f"# {args.dataset} group {args.group} {args.policy}: {len(actions)} recorded actions, replaying "
        f"{min(len(actions), args.boxes)}",
        flush=True,
    )
    print(
        "| variant | placed | collapse at | far drift per placement median / mean (µm) | box 0 (mm) | LS (mm) "
        "| rest drift 2 s (µm) | CPU s |",
        flush=True,
    )
    print("|---|---|---|---|---|---|---|---|", flush=True)
    for name in args.variants.split(","):
        row = replay(spec, actions, name, args.boxes)
        row.update(dataset=args.dataset, group=args.group, policy=args.policy, boxes=args.boxes)
        if args.out:
            with args.out.open("a") as fh:
                fh.write(json.dumps(row) + "\n")

        def f(v: float | None, fmt: str = ".1f") -> str:
            return "–" if v is None else format(v, fmt)

        print(
            f"| {name} | {row['placed']} | {row['collapse_at'] if row['collapse_at'] is not None else '–'} "
            f"| {f(row['far_drift_median_um'])} / {f(row['far_drift_mean_um'])} | {row['box0_mm']:.2f} "
            f"| {row['ls_mm']:.2f} | {row['rest_drift_um']:.1f} | {row['cpu_s']:.0f} |",
            flush=True,
        )
        if row["collapse"]:
            print(f"#   {name}: {row['collapse']}", flush=True)


if __name__ == "__main__":
    main()
