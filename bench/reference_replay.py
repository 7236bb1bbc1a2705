"""Replay our Math Pack plans in the reference simulator itself (packsim 0.0.4, its Execution Pack) and log
why each place plan went as it did. A fact-finding tool about the reference, not part of robobpp.

Two interpreters: robobpp's, and one with the reference's packages (install them into a separate virtual
environment, never into robobpp's: pandas trimesh scipy opencv-python-headless meshcat transforms3d pyvista gym
numba shapely easydict torch pybullet ompl tqdm matplotlib pyyaml; NumPy, PyBullet and OMPL as robobpp's).

    python bench/reference_replay.py export --dataset diverse --policy hm --group 0 --out DIR   # robobpp's
    REFERENCE_PYTHON bench/reference_replay.py run DIR       # the reference's
    python bench/reference_replay.py show DIR
    python bench/reference_replay.py trace DIR     # box by box: which phase moved which placed box, by how much

    # experiments on the reference itself: its Physics Pack (no robot), friction anchors on its boxes
    REFERENCE_PYTHON bench/reference_replay.py run DIR --setting 2 [--experiment anchors]

    # every (heuristic, group): export, run (JOBS at a time), then the table beside ours and the paper's
    nice python bench/paper_table.py --setting execution --open-loop --groups 5 --datasets diverse --json ours.json
    nice python bench/reference_replay.py batch --dataset diverse --groups 0-4 --out DIR --jobs 1 \
        --reference-python REFERENCE_PYTHON --ours ours.json --json table.json
    python bench/reference_replay.py report DIR --ours ours.json      # the table of the runs finished so far

``export`` runs the heuristic in our Math Pack on one train group and writes the reference's inputs: its action
list (rotation flag, x, y in its 1 cm cells), zero decision times, and the group's box sizes in its data format.
Long Board's plan goes as it is: the reference's packer works in a 250 × 120 container, as ours, and its main loop
itself swaps x and y (box sizes and positions) for its scene, whose container is 120 × 250.
``run`` (no robobpp import: the reference's interpreter) unpacks the reference's wheel (the one the dataset
importer keeps, or ``--wheel``) to a temporary directory and runs its own main loop in setting 3 on them,
unchanged but for compatibility shims that change nothing it simulates: NumPy 2 aliases (and ``np.cross`` on
2-vectors, gone in NumPy 2.5), a stand-in for PyMesh (box meshes built with trimesh), OMPL 2's Python bindings (the
validity checker passed as a callable, states from ``allocState``), a Python 3.11 fix in its unused network code,
and its wall-clock sleeps (2.2 s per box) skipped. Every place-plan check is logged: the IK error, whether the
start and the goal states are in collision (and with what), whether the search found an exact path, its wall and
CPU time and time limit; whether the operation was dangerous; which robot motion moved a placed box.

``run`` also writes ``trace.json``: every box's pose at each boundary of the reference's sequence for a box
(conveyor, pick, transfer, teleport and settle, homing, the settle its collapse rule reads), the simulation steps
between them and the robot bodies that touched a placed box (``trace`` prints it). ``--setting 2`` runs its
Physics Pack instead; ``--experiment anchors`` gives its boxes PyBullet's friction anchors (robobpp's physics
since version 3): an experiment, not the reference's figure.

``batch`` and ``report`` count each run as the reference does (its feasible boxes, their volume over the
container) and say how it ended (by what its main loop printed) and what decided each place-plan search:
``exact`` (a path found), ``goal_invalid`` (the pre-place pose in collision: the search runs to its time limit on
any machine) or ``limit`` (a free pose, no exact path within the limit). Its dangerous rule is wall time (a plan
over 15 s), and its time limits are wall time too: a ``limit`` search, and an ``exact`` one that still passed
15 s, depend on the CPU the search got (``search_cpu_share`` in the JSON: CPU over wall seconds of its
searches), a ``goal_invalid`` one does not.
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
    from robobpp.datasets.cache import wheels_dir
    from robobpp.datasets.sources import WHEEL_NAME
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
    out.mkdir(parents=True, exist_ok=True)
    (out / "action.json").write_text(json.dumps(actions))
    (out / "planning_time.json").write_text(json.dumps([0.0] * len(actions)))
    sizes = np.array([[b.length, b.width, b.height] for b in spec.boxes[: len(actions)]]) / 100
    (out / "sizes.json").write_text(json.dumps(sizes.tolist()))
    (out / "ours.json").write_text(
        json.dumps(
            {
                "dataset": dataset,
                "policy": policy,
                "group": group,
                "math_placed": len(actions),
                "wheel": str(wheels_dir() / WHEEL_NAME),  # so that ``run`` needs nothing of robobpp's
            }
        )
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


def _trace(trace: list[dict[str, Any]], setting: int) -> None:
    """Record where every box stands at each boundary of the reference's per-box sequence (its conveyor
    load, the pick, the transfer to the pre-place pose, the teleport and settle, the homing, the final
    settle its collapse rule reads), the simulation steps between them, and which robot body (arm link,
    suction parts, the carried box) touched which placed box in each robot motion. Reads only: nothing
    simulated changes (one ``getContactPoints`` per robot body per step; its robot moves by wall time, so
    a slower step moves it less per step)."""
    import pybullet as p
    from packsim import task
    from packsim.arm_pybullet_env.arm_envs import envs

    st: dict[str, Any] = {"phase": "start", "steps": 0, "scene": None, "box": None, "touch": {}}
    step = p.stepSimulation

    def placed(scene: Any) -> list[int]:
        return [int(b) for b in scene.packed_object_ids]

    def counted(*a: Any, **k: Any) -> Any:
        result = step(*a, **k)
        st["steps"] += 1
        scene = st["scene"]
        if setting == 3 and scene is not None and st["phase"] in ("pick", "transfer", "home"):
            mine = set(placed(scene))
            robot = scene.robot
            bodies = {"arm": robot.arm, "suction_base": robot.ee.base, "suction_head": robot.ee.body}
            if robot.ee.attach_obj_ids is not None:
                bodies["carried"] = robot.ee.attach_obj_ids
            for label, body in bodies.items():
                for c in p.getContactPoints(bodyA=body):
                    if c[2] in mine:
                        key = f"{st['phase']}|{label}|{c[3]}|{c[2]}"
                        hit = st["touch"].setdefault(key, [0, 0.0])
                        hit[0] += 1
                        hit[1] = max(hit[1], round(float(c[9]), 2))
        return result

    p.stepSimulation = counted

    def snap(label: str) -> None:
        scene = st["scene"]
        if scene is None:
            return
        ids = placed(scene)
        if st["box"] is not None and st["box"] not in ids:
            ids.append(st["box"])
        poses = {}
        for b in ids:
            pos, orn = p.getBasePositionAndOrientation(b)
            roll, pitch, yaw = (math.degrees(a) for a in p.getEulerFromQuaternion(orn))
            poses[str(b)] = [round(v, 5) for v in pos] + [round(yaw, 3), round(roll, 3), round(pitch, 3)]
        trace.append(
            {"at": label, "box": st["box"], "steps": st["steps"], "poses": poses, "touch": st["touch"]}
        )
        st["touch"] = {}

    def wrap(cls: Any, name: str, before: str | None, after: str | None, phase: str | None = None) -> None:
        original = getattr(cls, name)

        def wrapped(self: Any, *a: Any, **k: Any) -> Any:
            if name == "load_scene":
                st["scene"] = self
            if phase is not None and name == "ompl_and_execute" and st["phase"] != "placed":
                return original(self, *a, **k)  # only the homing after a placement
            if before:
                snap(before)
            if phase:
                st["phase"] = phase
            result = original(self, *a, **k)
            if name == "load_scene":
                st["box"] = int(self.box_ids[0])
            if name == "place_at":
                trace.append({"at": "target", "box": st["box"], "target": [round(v, 4) for v in result[2]]})
            if after:
                snap(after)
            st["phase"] = {"pick_block": "picked", "place_at": "placed", "move_ee_to": st["phase"]}.get(
                name, "settle"
            )
            return result

        setattr(cls, name, wrapped)

    wrap(task.Pack_Env, "load_scene", "collapse_check", "loaded", "load")
    wrap(task.Pack_Env, "pick_block", "before_pick", "picked", "pick")
    wrap(task.Pack_Env, "place_at", "before_place", "placed", "transfer")
    wrap(envs.Env, "ompl_and_execute", None, "homed", "home")

    move = envs.Env.move_ee_to

    def transfer(self: Any, *a: Any, **k: Any) -> Any:
        result = move(self, *a, **k)
        if st["phase"] == "transfer":
            snap("transferred")
            st["phase"] = "drop"
        return result

    envs.Env.move_ee_to = transfer
    st["snap"] = snap
    trace.append({"at": "setting", "setting": setting})
    _TRACE_STATE.update(st)


#: The tracer's state, so that ``run`` can take the last snapshot (the final collapse check) after the loop.
_TRACE_STATE: dict[str, Any] = {}


def _cross_2d(cross: Any) -> Any:
    """``np.cross`` as NumPy 1 had it for 2-vectors (the z component of the 3-vectors they extend)."""
    import numpy as np

    def crossed(a: Any, b: Any, *args: Any, **kwargs: Any) -> Any:
        a, b = np.asarray(a), np.asarray(b)
        if a.shape[-1:] == (2,) and b.shape[-1:] == (2,) and not args and not kwargs:
            return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        return cross(a, b, *args, **kwargs)

    return crossed


#: Experiments on the reference itself (``run --experiment``): each changes what it simulates, so a run with one
#: is not the reference's figure. ``anchors``: PyBullet's friction anchors on every box (robobpp's default since
#: physics version 3).
EXPERIMENTS = ("anchors",)


def _experiment(names: list[str]) -> None:
    import pybullet as p
    from packsim import task

    if "anchors" in names:
        add_box = task.Pack_Env.add_box

        def anchored(self: Any, *a: Any, **k: Any) -> Any:
            result = add_box(self, *a, **k)
            p.changeDynamics(result[0], -1, frictionAnchor=1)
            return result

        task.Pack_Env.add_box = anchored


def run(out: Path, wheel: Path | None = None, setting: int = 3, experiments: list[str] | None = None) -> None:
    import numpy as np
    import torch
    import yaml

    meta = json.loads((out / "ours.json").read_text())
    data = REFERENCE_DATA[meta["dataset"]]
    with tempfile.TemporaryDirectory() as tmp, zipfile.ZipFile(wheel or meta["wheel"]) as archive:
        archive.extractall(tmp)
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
        np.cross = _cross_2d(np.cross)  # NumPy ≥ 2.5 no longer takes 2-vectors (its hull test uses them)
        sys.path.insert(0, tmp)
        os.chdir(Path(tmp) / "packsim")  # its assets are found relative to here
        time.sleep = lambda _s: None  # its 2.2 s of sleeps per box; no simulation step depends on them
        sys.argv = sys.argv[:1]  # it parses the command line itself
        from packsim.main import main

        log: list[dict[str, Any]] = []
        _instrument(log, out)
        trace: list[dict[str, Any]] = []
        _trace(trace, setting)
        _experiment(experiments or [])
        try:
            text = main(
                {
                    "setting": setting,
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
            _TRACE_STATE["snap"]("end")
            (out / "trace.json").write_text(json.dumps(trace))
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
    row: list[Any] = []
    for e in log:
        if e["phase"] != "place" or e["box"] is None:
            continue
        first = e["box"] if first is None else first
        if e["ev"] == "check":
            row = [e["box"] - first, e["goal"], e["exact"], e["wall_s"], e["cpu_s"], e["limit_s"]]
        elif e["ev"] == "placed":
            row = row or [e["box"] - first, "–", "–", "–", "–", "–"]  # its Physics Pack plans nothing
            print("| " + " | ".join(str(v) for v in row) + f" | {e['dangerous']} | |")
            row = []
    for e in log:
        if e["ev"] == "moved":
            print(f"moved during {e['during']} (box {e['box']}): {e['dxy_m']} m")
    for line in text.splitlines():
        if line.startswith("Feasible Num"):
            n = int(line.split(":")[1])
            volume = sum(a * b * c for a, b, c in sizes[:n])
            print(f"{line}; Space Utilization of those boxes {volume / CONTAINERS_M3[meta['dataset']]:.3f}")


def show_trace(out: Path) -> None:
    """Box by box (``run``'s ``trace.json``): for each phase of the reference's sequence, its simulation steps,
    the largest horizontal move of a box placed before (which, by how much, cm), the robot bodies that touched
    placed boxes; at each collapse check the largest |dx| or |dy| of a placed box from its target."""
    trace = json.loads((out / "trace.json").read_text())
    phases = {
        ("collapse_check", "loaded"): "conveyor",
        ("loaded", "before_pick"): "wait",
        ("before_pick", "picked"): "pick",
        ("picked", "before_place"): "-",
        ("before_place", "transferred"): "transfer",
        ("transferred", "placed"): "drop+settle",
        ("before_place", "placed"): "drop+settle",
        ("placed", "homed"): "home",
        ("homed", "collapse_check"): "settle",
        ("homed", "end"): "settle",
        ("placed", "collapse_check"): "settle",
        ("placed", "end"): "settle",
    }
    targets: dict[str, list[float]] = {}
    snaps = [e for e in trace if "poses" in e]
    for e in trace:
        if e["at"] == "target":
            targets[str(e["box"])] = e["target"]
    first = next((e["box"] for e in snaps if e["box"] is not None), 0)
    print("| box | phase | steps | moved most (box: cm) | touched (phase, body, link → box: steps) |")
    print("|---:|---|---:|---|---|")
    for a, b in zip(snaps, snaps[1:], strict=False):
        phase = phases.get((a["at"], b["at"]), f"{a['at']}→{b['at']}")
        before = {k: v for k, v in a["poses"].items() if k != str(b["box"]) or a["at"] == "homed"}
        moves = [
            (math.hypot(b["poses"][k][0] - v[0], b["poses"][k][1] - v[1]) * 100, k)
            for k, v in before.items()
            if k in b["poses"] and k in targets
        ]
        most = max(moves, default=(0.0, None))
        touches = ", ".join(
            f"{key.split('|')[1]}/{key.split('|')[2]}→{int(key.split('|')[3]) - first}: {n}"
            for key, (n, _force) in sorted(b["touch"].items())
        )
        label = b["box"] - first if b["box"] is not None else "-"
        moved = f"{int(most[1]) - first}: {most[0]:.2f}" if most[1] is not None and most[0] >= 0.05 else ""
        print(f"| {label} | {phase} | {b['steps'] - a['steps']} | {moved} | {touches} |")
        if b["at"] in ("collapse_check", "end"):
            offs = [
                (max(abs(v[0] - targets[k][0]), abs(v[1] - targets[k][1])) * 100, k)
                for k, v in b["poses"].items()
                if k in targets
            ]
            worst = max(offs, default=(0.0, None))
            if worst[1] is not None:
                print(
                    f"| | **collapse check** | | largest offset: box {int(worst[1]) - first}, {worst[0]:.2f} cm | |"
                )


#: Container volumes (m³) as the reference divides by (its cells of 1 cm).
CONTAINERS_M3 = {"repetitive": 1.34 * 1.25 * 1.0, "diverse": 1.2 * 1.0 * 1.7, "longboard": 1.2 * 2.5 * 1.0}


#: How the reference's main loop ends an episode, by what it prints (first match; none: the plan ran out).
ENDINGS = (
    ("collapse", "Packing collapsed! Warning!"),
    ("dangerous_operations", "Dangerous operations of the robotic arm occurred more than"),
    ("place_plan_failed", "Move_ee_to fail!"),
    ("not_placeable", "This box is not placeable!"),
    ("add_failed", "Add_success fail!"),
)
#: The reference's dangerous rule: one place plan over this many seconds of wall time.
DANGEROUS_WALL_S = 15.0


def search_kind(check: dict[str, Any]) -> str:
    """What decided one logged place-plan search: ``goal_invalid`` (the pre-place pose in collision or out of
    IK reach: it searches to its time limit on any machine), ``exact`` (found a path), ``limit`` (a free goal,
    no exact path within the time limit: depends on how much CPU the search got)."""
    if check["goal"] != "ok":
        return "goal_invalid"
    return "exact" if check["exact"] else "limit"


def episode(sub: Path) -> dict[str, Any] | None:
    """One finished reference run, as the reference counts it: its feasible boxes, their volume over the
    container, how it ended, and what decided each place-plan search and each dangerous operation."""
    if not (sub / "reference.txt").exists():
        return None
    meta = json.loads((sub / "ours.json").read_text())
    sizes = json.loads((sub / "sizes.json").read_text())
    log = json.loads((sub / "reference.json").read_text())
    text = (sub / "reference.txt").read_text()
    placed = next(int(line.split(":")[1]) for line in text.splitlines() if line.startswith("Feasible Num"))
    printed = (sub / "run.log").read_text(errors="replace") if (sub / "run.log").exists() else None
    ending = "unknown" if printed is None else "plan_done"
    if printed is not None:
        for name, message in ENDINGS:
            if message in printed:
                ending = name
                break
    searches: dict[str, int] = {}
    dangerous: dict[str, int] = {}
    last: dict[str, Any] | None = None
    for e in log:
        if e["phase"] != "place":
            continue
        if e["ev"] == "check":
            last = e
            kind = search_kind(e)
            searches[kind] = searches.get(kind, 0) + 1
        elif e["ev"] == "placed" and e["dangerous"] and last is not None:
            # dangerous with an exact path: the search itself passed 15 s (a loaded machine)
            kind = search_kind(last)
            kind = "slow_exact" if kind == "exact" else kind
            dangerous[kind] = dangerous.get(kind, 0) + 1
    checks = [e for e in log if e["ev"] == "check" and e["phase"] == "place"]
    return {
        "policy": meta["policy"],
        "group": meta["group"],
        "math_placed": meta["math_placed"],
        "boxes": placed,
        "space_utilization": sum(a * b * c for a, b, c in sizes[:placed]) / CONTAINERS_M3[meta["dataset"]],
        "ending": ending,
        "searches": searches,
        "dangerous": dangerous,
        "search_cpu_share": round(
            sum(e["cpu_s"] for e in checks) / max(sum(e["wall_s"] for e in checks), 1e-9), 3
        ),
        "elapsed_s": float(text.split("All time is")[1].split()[0]) if "All time is" in text else None,
    }


def groups_of(text: str) -> list[int]:
    """``0-4`` or ``0,2,5`` or ``3``."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def batch(
    dataset: str,
    policies: list[str],
    groups: list[int],
    out: Path,
    jobs: int,
    reference_python: str,
    wheel: Path | None,
) -> None:
    """Export every (heuristic, group) not yet exported, run the reference on every one not yet run (``jobs`` at a
    time, each run's output kept in its folder's ``run.log``), then :func:`report`."""
    import subprocess
    from concurrent.futures import ThreadPoolExecutor

    todo = []
    for group in groups:  # group by group: a batch stopped early has every heuristic on its first groups
        for policy in policies:
            sub = out / f"{policy}-{group}"
            if not (sub / "ours.json").exists():
                export(dataset, policy, group, sub)
            if not (sub / "reference.txt").exists():
                todo.append(sub)

    def one(sub: Path) -> None:
        command = [reference_python, str(Path(__file__).resolve()), "run", str(sub)]
        command += ["--wheel", str(wheel)] if wheel else []
        t0 = time.time()
        with open(sub / "run.log", "w") as log:
            rc = subprocess.run(command, stdout=log, stderr=subprocess.STDOUT, check=False).returncode
        load = " ".join(f"{v:.2f}" for v in os.getloadavg())
        print(f"{sub.name}: exit {rc}, {time.time() - t0:.0f} s, load average {load}", flush=True)

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        list(pool.map(one, todo))


def report(outs: list[Path], dataset: str, ours_jsons: list[Path], json_out: Path | None) -> dict[str, Any]:
    """Per heuristic: the reference's mean Space Utilization over its finished runs and how they ended, beside
    ours on the same groups (each a ``paper_table.py --setting execution --open-loop --json`` file, named by its
    stem) and the paper's Execution figure; Spearman and mean |diff| against the paper for each, and in how many
    episodes ours placed as many boxes as the reference. A (heuristic, group) run in several of ``outs`` is taken
    from the first."""
    from paper_table import paper_figures

    from robobpp.paper import PAPER_HEURISTICS
    from robobpp.reproduction import spearman

    found: dict[tuple[str, int], dict[str, Any]] = {}
    for out in outs:
        for sub in sorted(out.iterdir()):
            e = episode(sub) if sub.is_dir() else None
            if e is not None:
                found.setdefault((e["policy"], e["group"]), e)
    runs = list(found.values())
    ours = {f.stem: json.loads(f.read_text())["ours"][dataset] for f in ours_jsons}
    paper = paper_figures("execution")[dataset]
    rows: dict[str, dict[str, Any]] = {}
    for policy in PAPER_HEURISTICS:
        mine = sorted((e for e in runs if e["policy"] == policy), key=lambda e: e["group"])
        if not mine:
            continue
        endings: dict[str, int] = {}
        for e in mine:
            endings[e["ending"]] = endings.get(e["ending"], 0) + 1
        row: dict[str, Any] = {
            "groups": [e["group"] for e in mine],
            "paper": paper[policy],
            "reference": sum(e["space_utilization"] for e in mine) / len(mine),
            "reference_boxes": sum(e["boxes"] for e in mine) / len(mine),
            "endings": endings,
        }
        for label, figures in ours.items():
            by_group = {x["group"]: x for x in figures.get(policy, {}).get("episodes", ())}
            if all(e["group"] in by_group for e in mine):
                row[label] = sum(by_group[e["group"]]["space_utilization"] for e in mine) / len(mine)
                row[f"{label}_same_boxes"] = sum(
                    by_group[e["group"]]["boxes_placed"] == e["boxes"] for e in mine
                )
        rows[policy] = row
    summary: dict[str, Any] = {}
    for who in ("reference", *ours):
        if rows and all(who in r for r in rows.values()):
            col, paper_col = [r[who] for r in rows.values()], [r["paper"] for r in rows.values()]
            ref_col = [r["reference"] for r in rows.values()]
            summary[who] = {
                "spearman": spearman(col, paper_col),
                "mean_abs_diff": sum(abs(a - b) for a, b in zip(col, paper_col, strict=True)) / len(col),
                # how far from the reference itself on the same plans and groups
                "spearman_vs_reference": spearman(col, ref_col),
                "mean_abs_diff_vs_reference": sum(abs(a - b) for a, b in zip(col, ref_col, strict=True))
                / len(col),
            }
    totals: dict[str, dict[str, int]] = {"searches": {}, "dangerous": {}}
    for e in runs:
        for key in totals:
            for kind, n in e[key].items():
                totals[key][kind] = totals[key].get(kind, 0) + n
    print(
        f"{dataset}, the reference (packsim 0.0.4's Execution Pack) replaying our Math Pack plans, train groups:"
    )
    labels = [q for q in ours if q in summary]
    print(
        "| heuristic | groups | paper | reference | diff | boxes | endings |"
        + "".join(f" {q} | same boxes |" for q in labels)
    )
    print("|---|---|---:|---:|---:|---:|---|" + "---:|---:|" * len(labels))
    for policy, r in rows.items():
        ending = ", ".join(f"{k} {v}" for k, v in sorted(r["endings"].items()))
        print(
            f"| {policy} | {len(r['groups'])} | {r['paper']:.3f} | {r['reference']:.3f} | "
            f"{r['reference'] - r['paper']:+.3f} | {r['reference_boxes']:.1f} | {ending} |"
            + "".join(f" {r[q]:.3f} | {r[q + '_same_boxes']} |" for q in labels)
        )
    for who, s in summary.items():
        rho = "–" if s["spearman"] is None else f"{s['spearman']:.2f}"
        line = f"{who}: against the paper Spearman {rho}, mean |diff| {s['mean_abs_diff']:.3f}"
        if who != "reference":
            vs = s["spearman_vs_reference"]
            line += (
                f"; against the reference Spearman {'–' if vs is None else f'{vs:.2f}'}, "
                f"mean |diff| {s['mean_abs_diff_vs_reference']:.3f}"
            )
        print(line)
    shares = sorted(e["search_cpu_share"] for e in runs)
    print(
        f"{len(runs)} runs; place-plan searches: {totals['searches']}; dangerous operations decided by: "
        f"{totals['dangerous']}; CPU share of the searches {shares[0]:.2f}–{shares[-1]:.2f}"
    )
    result = {"dataset": dataset, "rows": rows, "summary": summary, "totals": totals, "runs": runs}
    if json_out:
        json_out.write_text(json.dumps(result, indent=1))
    return result


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="step", required=True)
    ex = sub.add_parser("export")
    ex.add_argument("--dataset", choices=tuple(REFERENCE_DATA), default="diverse")
    ex.add_argument("--policy", default="hm")
    ex.add_argument("--group", type=int, default=0)
    ex.add_argument("--out", type=Path, required=True)
    for name in ("run", "show"):
        sub.add_parser(name).add_argument("out", type=Path)
    sub.choices["run"].add_argument(
        "--wheel", type=Path, help="the reference's wheel (default: the exported one)"
    )
    sub.choices["run"].add_argument(
        "--setting", type=int, choices=(2, 3), default=3, help="its Physics Pack (2) or Execution Pack (3)"
    )
    sub.choices["run"].add_argument(
        "--experiment",
        action="append",
        choices=EXPERIMENTS,
        default=[],
        help="change what the reference simulates (not its figure then; repeatable)",
    )
    sub.add_parser("trace", help="box by box: what moved the placed boxes, phase by phase").add_argument(
        "out", type=Path
    )
    ba = sub.add_parser("batch", help="export, run and report every (heuristic, group)")
    ba.add_argument("--dataset", choices=tuple(REFERENCE_DATA), default="diverse")
    ba.add_argument("--policies", default="dbl,hm,lsah,onlinebph,br,macs,sdfpack")
    ba.add_argument("--groups", default="0-4", help="e.g. 0-4 or 0,3,7")
    ba.add_argument("--out", type=Path, required=True)
    ba.add_argument("--jobs", type=int, default=1)
    ba.add_argument("--reference-python", required=True, help="the interpreter with the reference's packages")
    ba.add_argument("--wheel", type=Path)
    rep = sub.add_parser("report", help="the table of finished runs (a run in several folders: the first's)")
    for parsed in (ba, rep):
        parsed.add_argument(
            "--ours",
            type=Path,
            action="append",
            default=[],
            help="paper_table.py --setting execution --open-loop --json (repeatable)",
        )
        parsed.add_argument("--json", type=Path, help="also write the table and every run's record here")
    rep.add_argument("out", type=Path, nargs="+")
    rep.add_argument("--dataset", choices=tuple(REFERENCE_DATA), default="diverse")
    args = parser.parse_args()
    if args.step == "export":
        export(args.dataset, args.policy, args.group, args.out)
    elif args.step == "run":
        run(args.out.resolve(), args.wheel.resolve() if args.wheel else None, args.setting, args.experiment)
    elif args.step == "trace":
        show_trace(args.out)
    elif args.step == "batch":
        policies = [q for q in args.policies.split(",") if q]
        batch(
            args.dataset,
            policies,
            groups_of(args.groups),
            args.out,
            args.jobs,
            args.reference_python,
            args.wheel,
        )
        report([args.out], args.dataset, args.ours, args.json)
    elif args.step == "report":
        report(args.out, args.dataset, args.ours, args.json)
    else:
        show(args.out)


if __name__ == "__main__":
    main()
