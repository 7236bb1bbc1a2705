"""Replay one of our Math Pack plans in the reference simulator itself (packsim 0.0.4, its Execution Pack) and log
why each place plan went as it did. A fact-finding tool about the reference, not part of robobpp.

Two steps, two interpreters (the reference needs packages robobpp does not: install them into a separate
virtual environment, never into robobpp's):

    python bench/reference_replay.py export --dataset diverse --policy hm --group 0 --out DIR   # robobpp's
    REFERENCE_PYTHON bench/reference_replay.py run DIR      # pandas trimesh scipy opencv-python-headless meshcat
                                                             # transforms3d pyvista gym numba shapely easydict torch
                                                             # pybullet ompl
    python bench/reference_replay.py show DIR

``export`` runs the heuristic in our Math Pack on one train group and writes the reference's inputs: its action
list (rotation flag, x, y in its 1 cm cells), zero decision times, and the group's box sizes in its data format.
``run`` unpacks the wheel the dataset importer keeps to a temporary directory and runs its own main loop in
setting 3 on them, unchanged but for compatibility shims that change nothing it simulates: NumPy 2 aliases, a
stand-in for PyMesh (box meshes built with trimesh), OMPL 2's Python bindings (the validity checker passed as a
callable, states from ``allocState``), a Python 3.11 fix in its unused network code, and its wall-clock sleeps
(2.2 s per box) skipped. Every place-plan check is logged: the IK error, whether the start and the goal states
are in collision (and with what), whether the search found an exact path, its wall and CPU time and time limit;
whether the operation was dangerous; which robot motion moved a placed box. Its dangerous rule is wall time
(over 15 s), so on a loaded machine its searches get less CPU than the authors' and fail more often; the CPU
times in the log show it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any

#: The reference's dataset names and data-file stems.
REFERENCE_DATA = {"repetitive": "time_series", "diverse": "occupancy", "longboard": "flat_long"}
CONFIG_KEYS = {"time_series": "Time_series", "occupancy": "Occupancy", "flat_long": "Flat_long"}
#: Text replacements in the unpacked copy (file, old, new): API drift only.
SHIMS = (
    (
        "packsim/arm_pybullet_env/arm_envs/pb_ompl.py",
        "ob.StateValidityCheckerFn(self.is_state_valid)",
        "self.is_state_valid",
    ),
    ("packsim/arm_pybullet_env/arm_envs/pb_ompl.py", "ob.State(self.space)", "self.space.allocState()"),
    (
        "packsim/packer/pct_model/attention_model.py",
        "super(AttentionModelFixed, self).__getitem__(key)",
        "tuple.__getitem__(self, key)",
    ),
)
PYMESH_STANDIN = """
import numpy as np
import trimesh


class Mesh:
    def __init__(self, vertices, faces):
        self.vertices, self.faces = np.asarray(vertices, dtype=float), np.asarray(faces)


def load_mesh(path):
    mesh = trimesh.load(path, force="mesh", process=False)
    return Mesh(mesh.vertices, mesh.faces)


def form_mesh(vertices, faces):
    return Mesh(vertices, faces)
"""


def export(dataset: str, policy: str, group: int, out: Path) -> None:
    import numpy as np

    from robobpp.datasets import episode_specs
    from robobpp.episode import run_episode
    from robobpp.policies import load_policy
    from robobpp.replay import recorded_answers

    spec = episode_specs(dataset, "train", group + 1)[group]
    math_run = run_episode(spec, load_policy(policy), "math")
    answers, _ = recorded_answers(math_run)
    placed = [a for a in answers if a is not None]
    actions = [[int(a.orientation), round(a.x), round(a.y)] for a in placed]
    if any(abs(a.x - round(a.x)) > 1e-9 or abs(a.y - round(a.y)) > 1e-9 for a in placed):
        raise SystemExit("the plan is off the 1 cm grid; the reference takes cell indices")
    if dataset == "longboard":
        raise SystemExit("Long Board's frame is swapped in the reference; not exported")
    out.mkdir(parents=True, exist_ok=True)
    (out / "action.json").write_text(json.dumps(actions))
    (out / "planning_time.json").write_text(json.dumps([0.0] * len(actions)))
    sizes = np.array([[b.length, b.width, b.height] for b in spec.boxes[: len(actions)]]) / 100
    (out / "sizes.json").write_text(json.dumps(sizes.tolist()))
    (out / "ours.json").write_text(
        json.dumps({"dataset": dataset, "policy": policy, "group": group, "math_placed": len(actions)})
    )
    print(f"{dataset} {policy} group {group}: {len(actions)} actions written to {out}")


def _instrument(log: list[dict[str, Any]], out: Path) -> None:
    """Wrap the reference's place step and its reachability check to log what decided each operation."""
    import numpy as np
    import pybullet as p
    from packsim import task
    from packsim.arm_pybullet_env.arm_envs import envs
    from packsim.arm_pybullet_env.utils import ompl_utils, pybullet_utils

    state: dict[str, Any] = {"phase": "pick", "box": None}

    def note(**kw: Any) -> None:
        log.append({**kw, "phase": state["phase"], "box": state["box"]})

    place_at = task.Pack_Env.place_at

    def logged_place_at(self: Any, setting: int, body: int, position: Any, *a: Any, **k: Any) -> Any:
        state.update(phase="place", box=int(body))
        result = place_at(self, setting, body, position, *a, **k)
        note(ev="placed", move_success=bool(result[0]), dangerous=result[3])
        state["phase"] = "after"
        (out / "reference.json").write_text(json.dumps(log))
        return result

    task.Pack_Env.place_at = logged_place_at

    def why_invalid(env: Any, q: list[float], with_base: bool, with_body: bool) -> str:
        attached = [env.robot.ee.base] if with_base else []
        attached += [env.robot.ee.body] if with_body else []
        if env.robot.ee.attach_obj_ids is not None:
            attached.append(env.robot.ee.attach_obj_ids)
        iface = env.pb_ompl_interface
        iface.set_obstacles(env.obstacles, attached, True)
        current = env.robot.get_current_joints()
        iface.robot.set_state(q)
        why = "ok"
        for a, b in iface.check_link_pairs:
            if ompl_utils.pairwise_link_collision(iface.robot_id, a, iface.robot_id, b, max_distance=1e-5):
                why = f"self {a}-{b}"
                break
        for pairs, label in ((iface.check_body_pairs, "arm"), (iface.attach_check_body_pairs, "carried")):
            if why != "ok":
                break
            for body, other in pairs:
                if ompl_utils.pairwise_collision(body, other, max_distance=1e-5):
                    why = f"{label} vs body {other}"
                    break
        iface.robot.set_state(current)
        return why

    check = envs.Env.check_reachable

    def logged_check(
        self: Any,
        goal_pose: Any,
        allowed_time: float = 5,
        with_ee_base: bool = True,
        with_ee_body: bool = True,
        dist_threshold: float = 0.06,
    ) -> Any:
        pose = pybullet_utils.mat_to_pose(goal_pose) if len(goal_pose) > 2 else goal_pose
        current = self.robot.get_current_joints()
        q = [float(v) for v in self.robot.solve_ik(pose)]
        self.robot.robot_ompl.set_state(q)
        carried = self.robot.ee.attach_obj_ids
        turn = None
        if carried is not None:  # the carried box at the goal: its yaw (the target's is 0) and centre
            centre, quat = p.getBasePositionAndOrientation(carried)
            turn = [round(math.degrees(p.getEulerFromQuaternion(quat)[2]), 1), [round(v, 3) for v in centre]]
        miss = float(
            np.linalg.norm(np.array(pose[0]) - np.array(self.robot.get_link_pose(self.robot.ee_tip)[0]))
        )
        self.robot.robot_ompl.set_state(current)
        start = why_invalid(self, list(current), with_ee_base, with_ee_body)
        goal = why_invalid(self, q, with_ee_base, with_ee_body) if miss <= dist_threshold else "ik_miss"
        wall, cpu = time.time(), time.process_time()
        result = check(self, goal_pose, allowed_time, with_ee_base, with_ee_body, dist_threshold)
        exact = bool(self.pb_ompl_interface.ss.haveExactSolutionPath())
        note(
            ev="check",
            ok=bool(result[0]),
            ik_miss_m=round(miss, 4),
            start=start,
            goal=goal,
            exact=exact,
            wall_s=round(time.time() - wall, 2),
            cpu_s=round(time.process_time() - cpu, 2),
            limit_s=allowed_time,
            carried_yaw_deg_centre=turn,
            target=[round(float(v), 3) for v in pose[0]],
        )
        return result

    envs.Env.check_reachable = logged_check

    def placed_positions(env: Any) -> dict[int, tuple[float, ...]]:
        return {b: p.getBasePositionAndOrientation(b)[0] for b in env.obstacles if b > env.containers[0][-1]}

    for name in ("ompl_and_execute", "pick"):
        motion = getattr(envs.Env, name)

        def logged_motion(self: Any, *a: Any, _motion: Any = motion, _name: str = name, **k: Any) -> Any:
            before = placed_positions(self)
            result = _motion(self, *a, **k)
            after = placed_positions(self)
            moved = max(
                (
                    max(abs(after[b][0] - q[0]), abs(after[b][1] - q[1]))
                    for b, q in before.items()
                    if b in after
                ),
                default=0.0,
            )
            if moved > 0.005:
                note(ev="moved", during=_name, dxy_m=round(moved, 4))
            return result

        setattr(envs.Env, name, logged_motion)


def run(out: Path) -> None:
    import numpy as np
    import torch
    import yaml

    from robobpp.datasets.cache import wheels_dir
    from robobpp.datasets.sources import WHEEL_NAME

    meta = json.loads((out / "ours.json").read_text())
    data = REFERENCE_DATA[meta["dataset"]]
    with tempfile.TemporaryDirectory() as tmp, zipfile.ZipFile(wheels_dir() / WHEEL_NAME) as wheel:
        wheel.extractall(tmp)
        for rel, old, new in SHIMS:
            path = Path(tmp) / rel
            text = path.read_text()
            if old not in text:
                raise SystemExit(f"shim target not found in {rel}: {old}")
            path.write_text(text.replace(old, new))
        (Path(tmp) / "pymesh.py").write_text(PYMESH_STANDIN)
        sizes = torch.tensor(json.loads((out / "sizes.json").read_text()), dtype=torch.float64)
        torch.save({"data": sizes}, out / f"data_{data}_0.pt")
        config = yaml.safe_load((Path(tmp) / "packsim/configs/default.yaml").read_text())
        config["Data"][CONFIG_KEYS[data]]["data_path"] = str(out)
        (out / "config.yaml").write_text(yaml.safe_dump(config))
        np.float, np.int, np.math = float, int, math  # type: ignore[attr-defined]
        sys.path.insert(0, tmp)
        os.chdir(Path(tmp) / "packsim")  # its assets are found relative to here
        time.sleep = lambda _s: None  # its 2.2 s of sleeps per box; no simulation step depends on them
        sys.argv = sys.argv[:1]  # it parses the command line itself
        from packsim.main import main

        log: list[dict[str, Any]] = []
        _instrument(log, out)
        try:
            text = main(
                {
                    "setting": 3,
                    "data": data,
                    "method": "PCT",  # the only method name that reads action.json (decisions are the file's)
                    "test_data_config": 0,
                    "gui": 0,
                    "config": str(out / "config.yaml"),
                    "action_path": str(out / "action.json"),
                    "planning_time_path": str(out / "planning_time.json"),
                    "save_path": str(out),
                }
            )
        finally:
            (out / "reference.json").write_text(json.dumps(log))
        (out / "reference.txt").write_text(text)


def show(out: Path) -> None:
    log = json.loads((out / "reference.json").read_text())
    meta = json.loads((out / "ours.json").read_text())
    sizes = json.loads((out / "sizes.json").read_text())
    text = (out / "reference.txt").read_text() if (out / "reference.txt").exists() else ""
    print(f"{meta['dataset']} {meta['policy']} group {meta['group']}: Math placed {meta['math_placed']}")
    print("| box | goal state | exact path | wall s | CPU s | limit s | dangerous | moved (m) |")
    print("|---:|---|---|---:|---:|---:|---|---|")
    first = None
    for e in log:
        if e["phase"] != "place" or e["box"] is None:
            continue
        first = e["box"] if first is None else first
        if e["ev"] == "check":
            row = [e["box"] - first, e["goal"], e["exact"], e["wall_s"], e["cpu_s"], e["limit_s"]]
        elif e["ev"] == "placed":
            print("| " + " | ".join(str(v) for v in row) + f" | {e['dangerous']} | |")
    for e in log:
        if e["ev"] == "moved":
            print(f"moved during {e['during']} (box {e['box']}): {e['dxy_m']} m")
    for line in text.splitlines():
        if line.startswith("Feasible Num"):
            n = int(line.split(":")[1])
            volume = sum(a * b * c for a, b, c in sizes[:n])
            print(f"{line}; Space Utilization of those boxes {volume / CONTAINERS_M3[meta['dataset']]:.3f}")


#: Container volumes (m³) as the reference divides by (its cells of 1 cm).
CONTAINERS_M3 = {"repetitive": 1.34 * 1.25 * 1.0, "diverse": 1.2 * 1.0 * 1.7, "longboard": 1.2 * 2.5 * 1.0}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="step", required=True)
    ex = sub.add_parser("export")
    ex.add_argument("--dataset", choices=("repetitive", "diverse"), default="diverse")
    ex.add_argument("--policy", default="hm")
    ex.add_argument("--group", type=int, default=0)
    ex.add_argument("--out", type=Path, required=True)
    for name in ("run", "show"):
        sub.add_parser(name).add_argument("out", type=Path)
    args = parser.parse_args()
    if args.step == "export":
        export(args.dataset, args.policy, args.group, args.out)
    elif args.step == "run":
        run(args.out.resolve())
    else:
        show(args.out)


if __name__ == "__main__":
    main()
