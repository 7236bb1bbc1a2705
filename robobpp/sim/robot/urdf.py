"""Our own URDF of the IRB 6700-200/2.60 with a suction tool, generated from :mod:`facts`.

Collision shapes are primitives (boxes and cylinders) sized to the arm's public outline drawings,
generous rather than tight, so a path that clears them clears the real arm. Generated at run time
(and cached in the temporary directory under a content hash) so the joint table stays the single
source of truth.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass

from robobpp.sim.robot.facts import JOINTS, LINK_MASSES, TOOL

#: Link names as pybullet numbers them: link index i is LINK_NAMES[i] (the base is -1).
LINK_NAMES: tuple[str, ...] = ("link_1", "link_2", "link_3", "link_4", "link_5", "link_6", "tool", "tcp")
TOOL_LINK = LINK_NAMES.index("tool")
TCP_LINK = LINK_NAMES.index("tcp")


@dataclass(frozen=True, slots=True)
class Shape:
    kind: str  # "box" | "cylinder"
    size: tuple[float, ...]  # box: (x, y, z); cylinder: (radius, length)
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


_ALONG_X = (0.0, 1.5707963267948966, 0.0)

#: Collision/visual primitives per link, in the link frame (joint axis frames of the table).
SHAPES: dict[str, tuple[Shape, ...]] = {
    "base_link": (Shape("cylinder", (0.42, 0.50), (0.0, 0.0, 0.25)),),
    "link_1": (Shape("box", (0.80, 0.62, 0.36), (0.10, 0.0, -0.08)),),
    "link_2": (Shape("box", (0.26, 0.30, 1.20), (0.0, 0.0, 0.5625)),),
    "link_3": (Shape("box", (0.56, 0.36, 0.40), (-0.06, 0.0, 0.12)),),
    "link_4": (Shape("cylinder", (0.12, 0.92), (0.56, 0.0, 0.0), _ALONG_X),),
    "link_5": (Shape("box", (0.22, 0.22, 0.24), (0.0, 0.0, 0.0)),),
    "link_6": (Shape("cylinder", (0.10, 0.04), (-0.02, 0.0, 0.0), _ALONG_X),),
    # Stops 5 mm short of the TCP so the grasped box's top face is not a tool contact.
    "tool": (
        Shape(
            "cylinder", (TOOL.radius, TOOL.length - 0.015), ((TOOL.length - 0.005) / 2, 0.0, 0.0), _ALONG_X
        ),
    ),
    "tcp": (),
}


def _geometry(shape: Shape) -> str:
    if shape.kind == "box":
        return '<box size="{:g} {:g} {:g}"/>'.format(*shape.size)
    return '<cylinder radius="{:g}" length="{:g}"/>'.format(*shape.size)


def _link(name: str, mass: float) -> str:
    parts = [f'  <link name="{name}">']
    inertia = max(mass * 0.05, 1e-4)
    parts.append(
        f'    <inertial><origin xyz="0 0 0"/><mass value="{mass:g}"/>'
        f'<inertia ixx="{inertia:g}" iyy="{inertia:g}" izz="{inertia:g}" ixy="0" ixz="0" iyz="0"/></inertial>'
    )
    for shape in SHAPES[name]:
        origin = '<origin xyz="{:g} {:g} {:g}" rpy="{:g} {:g} {:g}"/>'.format(*shape.xyz, *shape.rpy)
        geometry = _geometry(shape)
        parts.append(f"    <visual>{origin}<geometry>{geometry}</geometry></visual>")
        parts.append(f"    <collision>{origin}<geometry>{geometry}</geometry></collision>")
    parts.append("  </link>")
    return "\n".join(parts)


def urdf_text() -> str:
    """The robot description as URDF XML."""
    axes = {"x": "1 0 0", "y": "0 1 0", "z": "0 0 1"}
    names = ("base_link",) + LINK_NAMES
    out = ['<?xml version="1.0"?>', '<robot name="abb_irb6700_200_260_suction">']
    out.append(_link("base_link", LINK_MASSES[0]))
    for i, joint in enumerate(JOINTS):
        out.append(_link(names[i + 1], LINK_MASSES[i + 1] if i + 1 < len(LINK_MASSES) else 10.0))
        out.append(
            f'  <joint name="{joint.name}" type="revolute"><parent link="{names[i]}"/><child link="{names[i + 1]}"/>'
            '<origin xyz="{:g} {:g} {:g}" rpy="0 0 0"/>'.format(*joint.origin)
            + f'<axis xyz="{axes[joint.axis]}"/>'
            f'<limit lower="{joint.lower:.6f}" upper="{joint.upper:.6f}" effort="10000" velocity="{joint.max_speed:.6f}"/>'
            "</joint>"
        )
    out.append(_link("tool", TOOL.mass))
    out.append(
        '  <joint name="flange-tool" type="fixed"><parent link="link_6"/><child link="tool"/>'
        '<origin xyz="0 0 0" rpy="0 0 0"/></joint>'
    )
    out.append(_link("tcp", 0.01))
    out.append(
        '  <joint name="tool-tcp" type="fixed"><parent link="tool"/><child link="tcp"/>'
        f'<origin xyz="{TOOL.length:g} 0 0" rpy="0 0 0"/></joint>'
    )
    out.append("</robot>")
    return "\n".join(out) + "\n"


def urdf_path() -> str:
    """A file holding :func:`urdf_text` (pybullet loads URDF from files only)."""
    text = urdf_text()
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    path = os.path.join(tempfile.gettempdir(), f"robobpp-irb6700-{digest}.urdf")
    if not os.path.exists(path):
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, path)
    return path
