"""Trace files → the compact payload the 3D replay viewer draws.

A trace is what ``EpisodeResult.to_dict()`` produces (one episode) or what ``robobpp evaluate --trace``
writes (``{"episodes": [...]}``). The viewer never sees the raw dicts: this module checks them (a trace file
is user input — it may be truncated, hand-edited or hostile) and keeps only what is drawn, so the page stays
small and the JavaScript can trust every number it gets.

Optional per-step fields the viewer understands (settings may add them to ``steps[*].extra``):

- ``collapsed_boxes``: indices of the boxes a collapse moved beyond the threshold (Physics Pack sets it);
  they are drawn red at that step.
- ``poses``: the actual placement of every box placed so far, after this step settled (Physics/Execution);
  without it a box is drawn where it landed when placed, and the final frame uses ``final[*].actual``.
  Either placement objects, or the Physics/Execution Packs' compact form ``[[x, y, z, qx, qy, qz, qw], ...]``
  (the box's *centre* in cm and its attitude, item i = box index i), expanded here with the extents of the
  step that placed each box, so the viewer always gets placement objects.
- ``tool_path_cm``: the tool-centre-point path of this placement, a list of ``[x, y, z]`` in the container
  frame, cm; ``tool_path_m`` is the same in metres (Execution Pack).
- ``track``: how boxes moved during the step (settling, a collapse, a shove), sampled over time
  (:mod:`robobpp.sim.physics.recording`); kept as the compact integers, the viewer scales them.
- ``motion`` and, on the first operation, ``cell``: the robot's joint angles over the operation and the
  robot cell they move in (:mod:`robobpp.sim.execution.recording`); ``cell`` becomes the payload's
  ``cell`` and the viewer draws the arm from it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

#: Bounds on what one trace may hold; a bigger file is refused with a clear message, not drawn slowly.
MAX_EPISODES = 500
MAX_STEPS = 5_000
MAX_PATH_POINTS = 2_000
MAX_FILE_BYTES = 200 * 1024 * 1024
#: Coordinates beyond this (cm) are nonsense for any container of the benchmark.
MAX_COORD_CM = 100_000.0
#: One step's robot waypoints and box samples; a step's time line (ms).
MAX_WAYPOINTS = 5_000
MAX_TRACK_SAMPLES = 2_000
#: A step's time line: at most 10 minutes, in ticks of at least 0.1 ms.
MAX_STEP_TICKS = 6_000_000
#: Quantised joint angles (10⁻⁴ rad) beyond two turns, positions (mm) and quaternions (10⁻⁴) beyond these
#: are nonsense.
MAX_Q_INT = 130_000
MAX_TRACK_MM = 1_000_000
MOTION_PHASES = ("pick", "transfer", "retreat")


class TraceError(ValueError):
    """The trace file cannot be drawn; the message says why."""


def read_trace(path: Path) -> list[dict[str, Any]]:
    """Read a trace file and return its episodes (checked, compact)."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise TraceError(f"cannot read {path}: {exc.strerror or exc}") from None
    if size > MAX_FILE_BYTES:
        raise TraceError(
            f"{path} is {size / 1e6:.0f} MB; the viewer reads at most {MAX_FILE_BYTES // 10**6} MB"
        )
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise TraceError(f"{path} is not UTF-8 text") from None
    except json.JSONDecodeError as exc:
        raise TraceError(
            f"{path} is not valid JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})"
        ) from None
    return episodes_from(data)


def episodes_from(data: Any) -> list[dict[str, Any]]:
    """Accept one episode dict or ``{"episodes": [...]}`` and return viewer payloads."""
    if isinstance(data, Mapping) and "episodes" in data:
        raw = data["episodes"]
        if not isinstance(raw, list):
            raise TraceError('"episodes" must be a list of episode objects')
    elif isinstance(data, Mapping):
        raw = [data]
    else:
        raise TraceError('a trace is an episode object or an object with a list under "episodes"')
    if not raw:
        raise TraceError("the trace holds no episode")
    if len(raw) > MAX_EPISODES:
        raise TraceError(f"the trace holds {len(raw)} episodes; the viewer shows at most {MAX_EPISODES}")
    return [viewer_payload(ep, where=f"episode {i}") for i, ep in enumerate(raw)]


def viewer_payload(episode: Any, *, where: str = "episode") -> dict[str, Any]:
    """Check one ``EpisodeResult.to_dict()`` and keep what the viewer draws."""
    ep = _mapping(episode, where)
    container = _mapping(ep.get("container"), f"{where}.container")
    dims = {
        k: _num(container.get(k), f"{where}.container.{k}", positive=True)
        for k in ("length", "width", "height")
    }
    steps_raw = ep.get("steps", [])
    if not isinstance(steps_raw, list):
        raise TraceError(f"{where}.steps must be a list")
    if len(steps_raw) > MAX_STEPS:
        raise TraceError(f"{where} has {len(steps_raw)} steps; the viewer shows at most {MAX_STEPS}")
    steps = [_step(s, f"{where}.steps[{i}]") for i, s in enumerate(steps_raw)]
    _expand_compact_poses(steps, where)
    cell = None
    for i, s in enumerate(steps_raw):
        extra = s.get("extra") if isinstance(s, Mapping) else None
        if isinstance(extra, Mapping) and extra.get("cell") is not None:
            cell = _cell(extra["cell"], f"{where}.steps[{i}].extra.cell")
            break
    for i, step in enumerate(steps):
        track = step.get("track")
        if track and any(row[0] > i for row in track["boxes"]):
            raise TraceError(f"{where}.steps[{i}].extra.track moves a box placed later")
    final_raw = ep.get("final", [])
    if not isinstance(final_raw, list):
        raise TraceError(f"{where}.final must be a list")
    final = []
    for i, f in enumerate(final_raw):
        fm = _mapping(f, f"{where}.final[{i}]")
        final.append(
            {
                "planned": _placement(fm.get("planned"), f"{where}.final[{i}].planned"),
                "actual": _placement(fm.get("actual"), f"{where}.final[{i}].actual"),
                "in_place": bool(fm.get("in_place", True)),
            }
        )
    metrics_raw = ep.get("metrics") or {}
    metrics = {
        str(k): (float(v) if isinstance(v, int | float) and math.isfinite(v) else None)
        for k, v in _mapping(metrics_raw, f"{where}.metrics").items()
    }
    return {
        "episode_id": _text(ep.get("episode_id", "")),
        "dataset": _text(ep.get("dataset", "")),
        "split": _text(ep.get("split", "")),
        "setting": _text(ep.get("setting", "")),
        "policy": _text(ep.get("policy", "")),
        "group": _int_or_none(ep.get("group")),
        "boxes_total": _int_or_none(ep.get("boxes_total")),
        "boxes_placed": _int_or_none(ep.get("boxes_placed")),
        "termination": _text(ep.get("termination", "")),
        "termination_detail": _text(ep.get("termination_detail", ""), limit=500),
        "container": dims,
        "metrics": metrics,
        "steps": steps,
        "final": final,
        "cell": cell,
    }


def _step(raw: Any, where: str) -> dict[str, Any]:
    s = _mapping(raw, where)
    box = _mapping(s.get("box"), f"{where}.box")
    out: dict[str, Any] = {
        "step": _int_or_none(s.get("step")),
        "box": {k: _num(box.get(k), f"{where}.box.{k}") for k in ("length", "width", "height")},
        "action": _action(s.get("action"), f"{where}.action"),
        "placement": None if s.get("placement") is None else _placement(s["placement"], f"{where}.placement"),
        "collapsed": bool(s.get("collapsed", False)),
        "termination": None if s.get("termination") is None else _text(s["termination"]),
        "decision_time": _num_or_none(s.get("decision_time")),
        "static_stability": _num_or_none(s.get("static_stability")),
        "trajectory_length_m": _num_or_none(s.get("trajectory_length_m")),
        "dangerous": None if s.get("dangerous") is None else bool(s["dangerous"]),
    }
    extra = s.get("extra") or {}
    if isinstance(extra, Mapping):
        moved = extra.get("collapsed_boxes")
        if isinstance(moved, list):
            out["collapsed_boxes"] = [v for v in moved[:MAX_STEPS] if _int_or_none(v) is not None]
        poses = extra.get("poses")
        if isinstance(poses, list):
            if len(poses) > MAX_STEPS:
                raise TraceError(f"{where}.extra.poses holds {len(poses)} boxes; at most {MAX_STEPS}")
            out["poses"] = [
                _compact_pose(p, f"{where}.extra.poses[{j}]")
                if isinstance(p, list | tuple)
                else _placement(p, f"{where}.extra.poses[{j}]")
                for j, p in enumerate(poses)
            ]
        if extra.get("tool_path_cm") is not None:
            out["tool_path"] = _path(extra["tool_path_cm"], 1.0, f"{where}.extra.tool_path_cm")
        elif extra.get("tool_path_m") is not None:
            out["tool_path"] = _path(extra["tool_path_m"], 100.0, f"{where}.extra.tool_path_m")
        if extra.get("motion") is not None:
            out["motion"] = _motion(extra["motion"], f"{where}.extra.motion")
        if extra.get("track") is not None:
            out["track"] = _track(extra["track"], f"{where}.extra.track")
    return out


def _ints(raw: Any, where: str, *, limit: int, bound: int, count: int | None = None) -> list[int]:
    if not isinstance(raw, list) or not all(type(v) is int for v in raw):
        raise TraceError(f"{where} must be a list of integers")
    if len(raw) > limit or (count is not None and len(raw) != count):
        raise TraceError(
            f"{where} holds {len(raw)} numbers; expected {count if count is not None else f'at most {limit}'}"
        )
    if raw and max(abs(min(raw)), abs(max(raw))) > bound:
        raise TraceError(f"{where} holds a value beyond {bound}")
    return raw


def _tick(raw: Any, where: str) -> float:
    tick = _num(raw, f"{where}.tick_s", positive=True)
    if not 1e-4 <= tick <= 0.1:
        raise TraceError(f"{where}.tick_s must be a simulation time step (0.1 ms to 0.1 s)")
    return tick


def _times(raw: Any, where: str, limit: int, tick: float) -> list[float]:
    """Times in ticks → ms for the viewer (checked: non-negative, in order)."""
    t = _ints(raw, where, limit=limit, bound=MAX_STEP_TICKS)
    if not t or t[0] < 0 or any(b < a for a, b in zip(t, t[1:], strict=False)):
        raise TraceError(f"{where} must be non-negative times, in order")
    if t[-1] * tick > 600:
        raise TraceError(f"{where} runs longer than 10 minutes")
    return [round(v * tick * 1000, 3) for v in t]


def _motion(raw: Any, where: str) -> dict[str, Any]:
    """The arm's joint time line of one operation (robobpp.sim.execution.recording)."""
    m = _mapping(raw, where)
    tick = _tick(m.get("tick_s"), where)
    t = _times(m.get("t"), f"{where}.t", MAX_WAYPOINTS, tick)
    q = _ints(m.get("q"), f"{where}.q", limit=6 * MAX_WAYPOINTS, bound=MAX_Q_INT, count=6 * len(t))
    phases = []
    for j, ph in enumerate(m.get("phases") or []):
        if not (isinstance(ph, list) and len(ph) == 3 and ph[0] in MOTION_PHASES):
            raise TraceError(f"{where}.phases[{j}] must be [{' | '.join(MOTION_PHASES)}, start ms, end ms]")
        phases.append([ph[0], *_times(ph[1:], f"{where}.phases[{j}]", 2, tick)])
    grip = _times(m.get("grip"), f"{where}.grip", 2, tick)
    carry = m.get("carry")
    if not isinstance(carry, list) or len(carry) != 7:
        raise TraceError(f"{where}.carry must be [x, y, z, qx, qy, qz, qw]")
    carry = [_num(v, f"{where}.carry") for v in carry]
    if len(grip) != 2 or math.hypot(*carry[3:]) < 1e-6:
        raise TraceError(f"{where}: grip must be [on ms, off ms] and carry a unit quaternion")
    return {"t": t, "q": q, "phases": phases, "grip": grip, "carry": carry}


def _track(raw: Any, where: str) -> dict[str, Any]:
    """Box poses sampled during one step (robobpp.sim.physics.recording)."""
    tr = _mapping(raw, where)
    t = _times(tr.get("t"), f"{where}.t", MAX_TRACK_SAMPLES, _tick(tr.get("tick_s"), where))
    rows = tr.get("boxes")
    if not isinstance(rows, list) or len(rows) > MAX_STEPS:
        raise TraceError(f"{where}.boxes must be a list of at most {MAX_STEPS} box tracks")
    boxes = []
    for j, row in enumerate(rows):
        row = _ints(row, f"{where}.boxes[{j}]", limit=2 + 7 * len(t), bound=MAX_TRACK_MM)
        if (
            len(row) < 9
            or (len(row) - 2) % 7
            or row[0] < 0
            or row[1] < 0
            or row[1] + (len(row) - 2) // 7 > len(t)
        ):
            raise TraceError(f"{where}.boxes[{j}] must be [box, first sample, 7 integers per sample]")
        boxes.append(row)
    return {"t": t, "boxes": boxes}


def _cell(raw: Any, where: str) -> dict[str, Any]:
    """The robot cell (robobpp.sim.execution.recording.cell): metres and radians."""
    c = _mapping(raw, where)

    def nums(value: Any, name: str, n: int) -> list[float]:
        if not isinstance(value, list) or len(value) != n:
            raise TraceError(f"{where}.{name} must be a list of {n} numbers")
        return [_num(v, f"{where}.{name}") for v in value]

    joints = c.get("joints")
    if not isinstance(joints, list) or len(joints) != 6:
        raise TraceError(f"{where}.joints must list the 6 joints")
    table = []
    for j, joint in enumerate(joints):
        if not isinstance(joint, list) or len(joint) != 6 or joint[0] not in ("x", "y", "z"):
            raise TraceError(f"{where}.joints[{j}] must be [axis, x, y, z, lower, upper]")
        table.append([joint[0], *nums(joint[1:], f"joints[{j}]", 5)])
    shapes = c.get("shapes")
    if not isinstance(shapes, list) or len(shapes) != 8:
        raise TraceError(f"{where}.shapes must hold the shapes of the base, six links and the tool")
    frames = []
    for j, frame in enumerate(shapes):
        if not isinstance(frame, list) or len(frame) > 8:
            raise TraceError(f"{where}.shapes[{j}] must be a list of shapes")
        out = []
        for k, shape in enumerate(frame):
            name = f"shapes[{j}][{k}]"
            if not (isinstance(shape, list) and len(shape) == 4 and shape[0] in ("box", "cylinder")):
                raise TraceError(f"{where}.{name} must be [box | cylinder, size, xyz, rpy]")
            size = nums(shape[1], f"{name}.size", 3 if shape[0] == "box" else 2)
            if min(size) <= 0:
                raise TraceError(f"{where}.{name}.size must be positive")
            out.append([shape[0], size, nums(shape[2], f"{name}.xyz", 3), nums(shape[3], f"{name}.rpy", 3)])
        frames.append(out)
    tool = nums(c.get("tool"), "tool", 2)
    conveyor = nums(c.get("conveyor"), "conveyor", 6)
    if min(tool) <= 0 or min(conveyor[3:]) <= 0:
        raise TraceError(f"{where}: tool and conveyor sizes must be positive")
    return {
        "base": nums(c.get("base"), "base", 4),
        "floor_z": _num(c.get("floor_z"), f"{where}.floor_z"),
        "joints": table,
        "tool": tool,
        "shapes": frames,
        "conveyor": conveyor,
        "pick": nums(c.get("pick"), "pick", 3),
        "home": nums(c.get("home"), "home", 6),
    }


def _placement(raw: Any, where: str) -> dict[str, Any]:
    p = _mapping(raw, where)
    out: dict[str, Any] = {k: _num(p.get(k), f"{where}.{k}") for k in ("x", "y", "z")}
    out.update({k: _num(p.get(k), f"{where}.{k}", positive=True) for k in ("length", "width", "height")})
    out["orientation"] = _int_or_none(p.get("orientation")) or 0
    out["index"] = _int_or_none(p.get("index"))
    q = p.get("quaternion")
    if q is not None:
        if not isinstance(q, list | tuple) or len(q) != 4:
            raise TraceError(f"{where}.quaternion must be [x, y, z, w]")
        quat = [_num(v, f"{where}.quaternion") for v in q]
        norm = math.sqrt(sum(v * v for v in quat))
        if norm < 1e-9:
            raise TraceError(f"{where}.quaternion has zero length")
        out["quaternion"] = [v / norm for v in quat]
    return out


def _compact_pose(raw: Any, where: str) -> list[float]:
    if len(raw) != 7:
        raise TraceError(f"{where} must be [x, y, z, qx, qy, qz, qw]")
    return [_num(v, where) for v in raw]


def _expand_compact_poses(steps: list[dict[str, Any]], where: str) -> None:
    """Compact poses (centre + quaternion, item i = box i) → placement objects with box i's extents."""
    extents: dict[int, dict[str, Any]] = {}
    for i, step in enumerate(steps):
        placed = step["placement"]
        if placed is not None and placed["index"] is not None:
            extents[placed["index"]] = placed
        poses = step.get("poses")
        if not poses:
            continue
        out = []
        for j, pose in enumerate(poses):
            if isinstance(pose, dict):
                out.append(pose)
                continue
            box = extents.get(j)
            if box is None:
                raise TraceError(f"{where}.steps[{i}].extra.poses[{j}]: box {j} was not placed by then")
            length, width, height = box["length"], box["width"], box["height"]
            q = pose[3:]
            norm = math.sqrt(sum(v * v for v in q))
            if norm < 1e-9:
                raise TraceError(f"{where}.steps[{i}].extra.poses[{j}] has a zero quaternion")
            out.append(
                {
                    "x": pose[0] - length / 2,
                    "y": pose[1] - width / 2,
                    "z": pose[2] - height / 2,
                    "length": length,
                    "width": width,
                    "height": height,
                    "orientation": box["orientation"],
                    "index": j,
                    "quaternion": [v / norm for v in q],
                }
            )
        step["poses"] = out


def _action(raw: Any, where: str) -> dict[str, float] | None:
    if raw is None:
        return None
    a = _mapping(raw, where)
    return {
        "x": _num(a.get("x"), f"{where}.x"),
        "y": _num(a.get("y"), f"{where}.y"),
        "orientation": _int_or_none(a.get("orientation")) or 0,
    }


def _path(raw: Any, scale: float, where: str) -> list[list[float]]:
    if not isinstance(raw, list):
        raise TraceError(f"{where} must be a list of [x, y, z] points")
    points = []
    for j, pt in enumerate(raw):
        if not isinstance(pt, list | tuple) or len(pt) != 3:
            raise TraceError(f"{where}[{j}] must be [x, y, z]")
        points.append([_num(v, f"{where}[{j}]") * scale for v in pt])
    return _thin(points, MAX_PATH_POINTS)


def _thin(points: list[list[float]], limit: int) -> list[list[float]]:
    """Keep at most ``limit`` points, always the first and the last (a path's ends matter most)."""
    if len(points) <= limit:
        return points
    stride = (len(points) - 1) / (limit - 1)
    return [points[round(i * stride)] for i in range(limit)]


def _mapping(raw: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(raw, Mapping):
        raise TraceError(f"{where} must be an object, got {type(raw).__name__}")
    return raw


def _num(raw: Any, where: str, *, positive: bool = False) -> float:
    if isinstance(raw, bool) or not isinstance(raw, int | float):
        raise TraceError(f"{where} must be a number, got {type(raw).__name__}")
    value = float(raw)
    if not math.isfinite(value) or abs(value) > MAX_COORD_CM:
        raise TraceError(f"{where} = {raw!r} is out of range")
    if positive and value <= 0:
        raise TraceError(f"{where} must be positive, got {raw!r}")
    return value


def _num_or_none(raw: Any) -> float | None:
    if isinstance(raw, bool) or not isinstance(raw, int | float) or not math.isfinite(raw):
        return None
    return float(raw)


def _int_or_none(raw: Any) -> int | None:
    if isinstance(raw, bool) or not isinstance(raw, int):
        return None
    return raw


def _text(raw: Any, *, limit: int = 200) -> str:
    return str(raw)[:limit]
