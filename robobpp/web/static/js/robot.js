// The IRB 6700 of a replay, built from the trace's robot cell (robobpp/sim/execution/recording.py): the
// simulator's joint table and link shapes. One Object3D per joint frame turns about its axis, so the
// forward kinematics is the scene graph of that table and nothing robot-specific is written here.
import * as THREE from "three";

const ARM_COLOR = 0xf26a0f; // the robot's links; the browser tests look for this hue
const JOINT_COLOR = 0x374151;
const Q_UNIT = 1e-4; // rad: joint angles are integers of 10⁻⁴ rad in the trace

// Index of the last entry of the ascending `times` that is <= t (0 when t precedes them all).
export function bracket(times, t) {
  let lo = 0;
  let hi = times.length - 1;
  while (lo < hi) {
    const mid = (lo + hi + 1) >> 1;
    if (times[mid] <= t) lo = mid; else hi = mid - 1;
  }
  return lo;
}

// Joint angles (rad) of a step's motion at `ms` into the step: joint-linear between waypoints, as driven.
export function jointsAt(motion, ms) {
  const { t, q } = motion;
  const i = bracket(t, ms);
  const j = Math.min(i + 1, t.length - 1);
  const f = j > i && t[j] > t[i] ? Math.min(1, Math.max(0, (ms - t[i]) / (t[j] - t[i]))) : 0;
  const out = new Array(6);
  for (let k = 0; k < 6; k += 1) out[k] = (q[6 * i + k] + f * (q[6 * j + k] - q[6 * i + k])) * Q_UNIT;
  return out;
}

export class Robot {
  constructor(cell) {
    this.cell = cell;
    this.root = new THREE.Group();
    const [bx, by, bz, yaw] = cell.base;
    this.root.position.set(bx * 100, by * 100, bz * 100);
    this.root.rotation.z = yaw;
    this.root.scale.setScalar(100); // the cell is in metres, the scene in cm
    const arm = new THREE.MeshStandardMaterial({ color: ARM_COLOR, roughness: 0.5, metalness: 0.1 });
    const dark = new THREE.MeshStandardMaterial({ color: JOINT_COLOR, roughness: 0.6, metalness: 0.2 });
    const axes = { x: new THREE.Vector3(1, 0, 0), y: new THREE.Vector3(0, 1, 0), z: new THREE.Vector3(0, 0, 1) };
    Robot.addShapes(this.root, cell.shapes[0], dark);
    let parent = this.root;
    this.joints = cell.joints.map(([axis, x, y, z], i) => {
      const node = new THREE.Object3D();
      node.position.set(x, y, z);
      node.userData.axis = axes[axis];
      parent.add(node);
      Robot.addShapes(node, cell.shapes[i + 1], i >= 4 ? dark : arm);
      parent = node;
      return node;
    });
    const flange = this.joints[5];
    Robot.addShapes(flange, cell.shapes[7], dark);
    const [toolLength, toolRadius] = cell.tool;
    const cup = new THREE.Mesh(new THREE.CylinderGeometry(toolRadius * 1.6, toolRadius * 1.6, 0.02, 24).rotateZ(Math.PI / 2), dark);
    cup.position.set(toolLength - 0.01, 0, 0);
    flange.add(cup);
    this.tcp = new THREE.Object3D();
    this.tcp.position.set(toolLength, 0, 0);
    flange.add(this.tcp);
    // The carried box rides on the TCP at the pose the trace gives (box frame in the TCP frame, metres).
    this.carried = new THREE.Group();
    this.tcp.add(this.carried);
    this.setJoints(cell.home);
  }

  static addShapes(node, shapes, material) {
    for (const [kind, size, xyz, rpy] of shapes) {
      const geometry = kind === "box"
        ? new THREE.BoxGeometry(size[0], size[1], size[2])
        // URDF cylinders lie along z, three.js's along y.
        : new THREE.CylinderGeometry(size[0], size[0], size[1], 28).rotateX(Math.PI / 2);
      const mesh = new THREE.Mesh(geometry, material);
      mesh.position.set(xyz[0], xyz[1], xyz[2]);
      mesh.rotation.set(rpy[0], rpy[1], rpy[2], "ZYX"); // URDF rpy: Rz(yaw) Ry(pitch) Rx(roll)
      node.add(mesh);
    }
  }

  setJoints(q) {
    this.joints.forEach((node, i) => node.quaternion.setFromAxisAngle(node.userData.axis, q[i]));
    this.root.updateMatrixWorld(true);
  }

  tcpWorld() {
    return new THREE.Vector3().setFromMatrixPosition(this.tcp.matrixWorld);
  }
}
