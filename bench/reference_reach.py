"""Does the reference's robot reach its own pre-place poses? (A fact about packsim 0.0.4, not about robobpp.)

packsim ends an Execution episode when its IK misses the place pose by more than 6 cm ("Move_ee_to fail"). Its IK
is pybullet's damped least squares on its IRB 6700 URDF (100 iterations, rest pose = home, all 8 moving joints),
started from where the arm is: after a pick at its conveyor station (its first yaw try, 90°) and a lift of joint 2
by 0.3 rad. This loads the URDF from the packsim wheel the dataset importer keeps (read at run time, nothing of it
is copied) and asks that IK, from that state, for the tool tip 0.35 m above box centres on a grid of each
dataset's container in the reference's layout (its container origins; 1.02 cm per cell).

    python bench/reference_reach.py
"""

from __future__ import annotations

import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pybullet as p

from robobpp.datasets.cache import wheels_dir
from robobpp.datasets.sources import WHEEL_NAME

MODELS = "packsim/arm_pybullet_env/arm_envs/models/irb6700/"
#: The reference's containers (cells, its frame) and their origins (m), from its configs/default.yaml.
CONTAINERS = {
    "repetitive": ((134, 125, 100), (0.9, -0.6, 0.025)),
    "diverse": ((120, 100, 170), (1.1, -0.5, 0.025)),
    "longboard": ((120, 250, 100), (0.9, -1.0, 0.025)),
}
PITCH = 0.0102  # m per cell: 1 cm + the reference's 0.2 mm gap
PICK = (1.5706, -1.7414, 0.378)  # its pick point (x, y) and conveyor top (z), m
TIP = 10  # the tool tip link


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp, zipfile.ZipFile(wheels_dir() / WHEEL_NAME) as wheel:
        wheel.extractall(tmp, [n for n in wheel.namelist() if n.startswith(MODELS)])
        client = p.connect(p.DIRECT)
        arm = p.loadURDF(str(Path(tmp) / MODELS / "irb6700.urdf"), [0, 0, -0.001], physicsClientId=client)
        joints = [
            j
            for j in range(p.getNumJoints(arm, physicsClientId=client))
            if p.getJointInfo(arm, j, physicsClientId=client)[2] in (p.JOINT_REVOLUTE, p.JOINT_PRISMATIC)
        ]
        info = [p.getJointInfo(arm, j, physicsClientId=client) for j in joints]
        lower, upper = [i[8] for i in info], [i[9] for i in info]
        home = [0.0] * len(joints)

        def set_q(q: list[float] | np.ndarray) -> None:
            for j, v in zip(joints, q, strict=True):
                p.resetJointState(arm, j, float(v), physicsClientId=client)

        def reach(
            target: np.ndarray, quat: tuple[float, ...], start: np.ndarray | list[float]
        ) -> np.ndarray | None:
            set_q(start)
            q = np.asarray(
                p.calculateInverseKinematics(
                    arm,
                    TIP,
                    target.tolist(),
                    list(quat),
                    lowerLimits=lower,
                    upperLimits=upper,
                    jointRanges=[u - lo for u, lo in zip(upper, lower, strict=True)],
                    restPoses=home,
                    maxNumIterations=100,
                    residualThreshold=1e-5,
                    physicsClientId=client,
                ),
                dtype=np.float32,
            )
            q[2:] = (q[2:] + np.pi) % (2 * np.pi) - np.pi
            set_q(q)
            got = np.array(p.getLinkState(arm, TIP, computeForwardKinematics=True, physicsClientId=client)[4])
            return q if np.linalg.norm(got - target) <= 0.06 else None

        print("| dataset | box height (m) | pre-place poses reached (grid 7 × 7 × 4 levels) |")
        print("|---|---:|---:|")
        for height in (0.1, 0.3):
            picked = reach(
                np.array([PICK[0], PICK[1], PICK[2] + height]),
                p.getQuaternionFromEuler((0, 0, np.pi / 2)),
                home,
            )
            # Reached at the first yaw try: the box hangs 90° off its target on the tool until the teleport.
            print(
                f"| pick of a {height} m box at the first yaw try (90°) | | {'reached' if picked is not None else 'missed'} |"
            )
            start = np.array(home if picked is None else picked)
            start[1] -= 0.3  # the lift after the grasp
            for name, (cells, origin) in CONTAINERS.items():
                size = np.array(cells) * PITCH
                hits = total = 0
                for fz in (0.0, 0.25, 0.5, 0.75):
                    for fx in np.linspace(0.05, 0.95, 7):
                        for fy in np.linspace(0.05, 0.95, 7):
                            z = min(fz * size[2], size[2] - height) + height / 2
                            centre = np.array(origin) + [fx * size[0], fy * size[1], z]
                            hits += reach(centre + [0, 0, 0.35], (0, 0, 0, 1), start) is not None
                            total += 1
                print(f"| {name} | {height} | {hits} / {total} |")
        p.disconnect(client)


if __name__ == "__main__":
    main()
