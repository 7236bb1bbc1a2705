// robobpp episode replay: a three.js view of a trace over time.
//
// The page holds the markup (templates/_replay.html) and the trace as JSON in <script id="trace-data">
// (already checked and trimmed by robobpp/web/trace.py). The time line runs from 0 to the number of steps:
// position k is the state after k steps (0 = empty container, the last = the final settled state), and
// between k-1 and k step k happens — the robot's pick, transfer and retreat (Execution Pack) and the boxes
// settling or falling (Physics and Execution Packs), from the step's recorded motion and box track.
// The robot is drawn from the trace's `cell`: the simulator's own joint table and link shapes, so the
// forward kinematics here is the scene graph of that table and nothing robot-specific is written twice.
// The same file runs on the server's replay page and in `robobpp view`'s offline page.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { Robot, bracket, jointsAt } from "robobpp/robot.js";
import { TERMINATION_TEXT, episodeRows, overlayText, setKV, stepRows } from "robobpp/replay_info.js";

// Viridis from a quarter up (its darkest end hides edges and shading), then interpolated in sRGB.
const VIRIDIS = ["#3b528b", "#2c728e", "#21918c", "#27ad81", "#5ec962", "#aadc32", "#fde725"]
  .map((hex) => { const c = new THREE.Color(hex); return [c.r, c.g, c.b]; });
const COLLAPSE_COLOR = new THREE.Color("#e11d48");
const PATH_COLOR = new THREE.Color("#8b5cf6");
// Collapse thresholds of docs/benchmark.md, "Datasets" (cm): a box displaced further than this is drawn as collapsed.
const THRESHOLDS = { repetitive: 7, diverse: 4, longboard: 7 };
// Units of the compact box tracks (robobpp/sim/physics/recording.py).
const TRACK_CM = 0.1; // mm -> cm
const TRACK_QUAT = 1e-4;
// A step with nothing timed (or a very short one) still takes this long at 1×, so every box is seen.
const MIN_STEP_S = 0.4;
const SPEEDS = [0.25, 0.5, 1, 2, 4, 8, 16];
function viridis(t) {
  const x = Math.min(1, Math.max(0, t)) * (VIRIDIS.length - 1);
  const i = Math.min(VIRIDIS.length - 2, Math.floor(x));
  const f = x - i;
  const a = VIRIDIS[i];
  const b = VIRIDIS[i + 1];
  return new THREE.Color(a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f);
}

// Rotation of a box: the quaternion's attitude, less the nominal 90° yaw already in the swapped extents
// (settings may report the quaternion with or without it; a resting box's yaw tells which).
function boxRotation(p) {
  if (!p.quaternion) return null;
  const [x, y, z, w] = p.quaternion;
  const q = new THREE.Quaternion(x, y, z, w);
  if (p.orientation === 1) {
    const yaw = new THREE.Euler().setFromQuaternion(q, "ZYX").z;
    const quarter = Math.abs(Math.abs(yaw) - Math.PI / 2) < Math.PI / 4;
    if (quarter) q.multiply(new THREE.Quaternion().setFromAxisAngle(new THREE.Vector3(0, 0, 1), -Math.sign(yaw) * Math.PI / 2));
  }
  return q;
}

function center(p) {
  return new THREE.Vector3(p.x + p.length / 2, p.y + p.width / 2, p.z + p.height / 2);
}

class Replay {
  constructor(root, episodes) {
    this.root = root;
    this.episodes = episodes;
    this.el = (role) => root.querySelector(`[data-role="${role}"]`);
    this.canvas = this.el("canvas");
    this.overlay = this.el("overlay");
    this.slider = this.el("slider");
    this.u = 0;
    this.playing = false;
    this.speed = 1;
    this.unitBox = new THREE.BoxGeometry(1, 1, 1);
    this.unitEdges = new THREE.EdgesGeometry(this.unitBox);
    this.edgeMaterial = new THREE.LineBasicMaterial({ color: 0x1e293b, transparent: true, opacity: 0.55 });
    this.currentEdgeMaterial = new THREE.LineBasicMaterial({ color: 0x000000 });
    this.collapseMaterial = new THREE.MeshStandardMaterial({ color: COLLAPSE_COLOR, emissive: 0x5b0a1c, roughness: 0.55 });
    this.initRenderer();
    this.bindControls();
    const select = this.el("episode");
    episodes.forEach((ep, i) => {
      const option = document.createElement("option");
      option.value = String(i);
      option.textContent = `${i + 1}. ${ep.dataset || "?"} · ${ep.setting || "?"} · group ${ep.group ?? "?"} · ${ep.policy || "?"}`;
      select.append(option);
    });
    select.disabled = episodes.length < 2;
    select.addEventListener("change", () => this.load(Number(select.value)));
    this.load(0);
  }

  initRenderer() {
    try {
      this.renderer = new THREE.WebGLRenderer({ canvas: this.canvas, antialias: true, alpha: true, preserveDrawingBuffer: true });
    } catch (err) {
      this.renderer = null;
      this.overlay.textContent = "This browser offers no WebGL: the 3D view is off, the step figures still work.";
      return;
    }
    this.renderer.setPixelRatio(window.devicePixelRatio || 1);
    this.scene = new THREE.Scene();
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0xb0bccb, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.9);
    sun.position.set(-0.6, -1.0, 1.6);
    this.scene.add(sun);
    this.camera = new THREE.PerspectiveCamera(38, 1, 1, 50000);
    this.camera.up.set(0, 0, 1);
    this.controls = new OrbitControls(this.camera, this.canvas);
    this.controls.enableDamping = false;
    this.controls.addEventListener("change", () => this.render());
    this.staticGroup = new THREE.Group();
    this.boxGroup = new THREE.Group();
    this.extraGroup = new THREE.Group();
    this.scene.add(this.staticGroup, this.boxGroup, this.extraGroup);
    new ResizeObserver(() => this.resize()).observe(this.canvas);
  }

  bindControls() {
    this.el("first").addEventListener("click", () => { this.stop(); this.show(0); });
    this.el("last").addEventListener("click", () => { this.stop(); this.show(this.frames); });
    this.el("prev").addEventListener("click", () => this.stepBy(-1));
    this.el("next").addEventListener("click", () => this.stepBy(1));
    this.el("play").addEventListener("click", () => this.togglePlay());
    const speed = this.el("speed");
    if (speed) {
      for (const s of SPEEDS) {
        const option = document.createElement("option");
        option.value = String(s);
        option.textContent = `${s}×`;
        speed.append(option);
      }
      speed.value = "1";
      speed.addEventListener("change", () => { this.speed = Number(speed.value) || 1; });
    }
    this.slider.addEventListener("input", () => { this.stop(); this.show(Number(this.slider.value)); });
    document.addEventListener("keydown", (event) => {
      const tag = event.target && event.target.tagName;
      if (tag === "SELECT" || tag === "TEXTAREA" || (tag === "INPUT" && event.target !== this.slider)) return;
      if (event.key === "ArrowRight") { this.stepBy(1); event.preventDefault(); }
      else if (event.key === "ArrowLeft") { this.stepBy(-1); event.preventDefault(); }
      else if (event.key === " " && event.target === document.body) { this.togglePlay(); event.preventDefault(); }
    });
  }

  // -- the episode ------------------------------------------------------------------------------------
  load(index) {
    this.stop();
    this.episode = this.episodes[index];
    const ep = this.episode;
    this.frames = ep.steps.length;
    this.indexOf = new Map();
    ep.steps.forEach((s, i) => {
      if (s.placement && s.placement.index !== null && s.placement.index !== undefined) this.indexOf.set(s.placement.index, i);
    });
    this.total = Math.max(1, this.frames);
    // Seconds each step's recorded content lasts (motion, box track); 0 when nothing is timed.
    this.durations = ep.steps.map((s) => {
      let ms = 0;
      if (s.motion) ms = Math.max(ms, s.motion.t[s.motion.t.length - 1], ...s.motion.phases.map((p) => p[2]));
      if (s.track) ms = Math.max(ms, s.track.t[s.track.t.length - 1]);
      return ms / 1000;
    });
    this.timed = this.durations.some((d) => d > 0);
    this.slider.max = String(this.frames);
    this.slider.step = this.timed ? "any" : "1";
    this.buildTimeline();
    this.showEpisodeInfo();
    this.boxes = new Map();
    this.pathKey = null;
    if (this.renderer) {
      this.boxGroup.clear();
      this.buildStatic();
    }
    this.show(0);
  }

  // Marks on the time line under the slider: collapses, dangerous operations, the step that ended it.
  buildTimeline() {
    const line = this.el("timeline");
    if (!line) return;
    line.replaceChildren();
    this.episode.steps.forEach((s, i) => {
      const kinds = [];
      if (s.collapsed) kinds.push(["collapse", "collapse"]);
      if (s.dangerous) kinds.push(["dangerous", "dangerous operation"]);
      if (s.termination && s.termination !== "completed" && !s.collapsed) kinds.push(["ended", TERMINATION_TEXT[s.termination] || s.termination]);
      for (const [kind, text] of kinds) {
        const mark = document.createElement("button");
        mark.type = "button";
        mark.className = `mark ${kind}`;
        mark.style.left = `${((i + 0.5) / this.total) * 100}%`;
        mark.title = `step ${i + 1}: ${text}`;
        mark.setAttribute("aria-label", mark.title);
        mark.addEventListener("click", () => { this.stop(); this.show(i + 1); });
        line.append(mark);
      }
    });
  }

  buildStatic() {
    const ep = this.episode;
    const { length: L, width: W, height: H } = ep.container;
    this.staticGroup.clear();
    this.extraGroup.clear();
    const cell = ep.cell;
    const floor = cell ? cell.floor_z * 100 : -3;
    const pallet = new THREE.Mesh(new THREE.BoxGeometry(L, W, -floor), new THREE.MeshStandardMaterial({ color: 0xc9a57b, roughness: 0.9 }));
    pallet.position.set(L / 2, W / 2, floor / 2);
    this.staticGroup.add(pallet);
    const outline = new THREE.LineSegments(new THREE.EdgesGeometry(new THREE.BoxGeometry(L, W, H)),
      new THREE.LineDashedMaterial({ color: 0x64748b, dashSize: 4, gapSize: 3 }));
    outline.position.set(L / 2, W / 2, H / 2);
    outline.computeLineDistances();
    this.staticGroup.add(outline);
    const axes = new THREE.AxesHelper(Math.min(L, W) * 0.25);
    axes.position.set(0, 0, 0.2);
    this.staticGroup.add(axes);
    this.robot = null;
    if (cell) this.buildCell(cell);
    const bounds = new THREE.Box3().setFromObject(this.staticGroup);
    if (this.robot) bounds.union(new THREE.Box3().setFromObject(this.robot.root));
    const size = bounds.getSize(new THREE.Vector3());
    const grid = new THREE.GridHelper(Math.max(size.x, size.y) * 1.6, 30, 0xb8c2cf, 0xd5dce4);
    grid.rotation.x = Math.PI / 2;
    const mid = bounds.getCenter(new THREE.Vector3());
    grid.position.set(mid.x, mid.y, floor - 0.05);
    this.staticGroup.add(grid);
    // Frame the whole cell (container, robot, conveyor) from the front-left, a little above.
    const radius = 0.5 * size.length();
    const distance = (1.02 * radius) / Math.sin(THREE.MathUtils.degToRad(this.camera.fov / 2));
    const direction = new THREE.Vector3(-0.55, -0.8, 0.62).normalize();
    const target = cell ? mid.clone().setZ(Math.max(H * 0.42, mid.z * 0.8)) : new THREE.Vector3(L / 2, W / 2, H * 0.42);
    this.camera.position.copy(target).addScaledVector(direction, distance);
    this.camera.far = distance * 10;
    this.controls.target.copy(target);
    this.controls.update();
    this.resize();
  }

  // The robot cell: pedestal, conveyor with its pick point, and the arm.
  buildCell(cell) {
    const [bx, by, bz] = cell.base;
    const floor = cell.floor_z * 100;
    const concrete = new THREE.MeshStandardMaterial({ color: 0x9ca3af, roughness: 0.9 });
    const pedestal = new THREE.Mesh(new THREE.BoxGeometry(100, 100, bz * 100 - floor), concrete);
    pedestal.position.set(bx * 100, by * 100, (bz * 100 + floor) / 2);
    this.staticGroup.add(pedestal);
    const [cx, cy, cz, hx, hy, hz] = cell.conveyor.map((v) => v * 100);
    const conveyor = new THREE.Mesh(new THREE.BoxGeometry(2 * hx, 2 * hy, 2 * hz), new THREE.MeshStandardMaterial({ color: 0x4b5563, roughness: 0.8 }));
    conveyor.position.set(cx, cy, cz);
    this.staticGroup.add(conveyor);
    const belt = new THREE.Mesh(new THREE.BoxGeometry(2 * hx * 0.92, 2 * hy * 0.98, 0.6), new THREE.MeshStandardMaterial({ color: 0x1f2937, roughness: 0.95 }));
    belt.position.set(cx, cy, cz + hz + 0.3);
    this.staticGroup.add(belt);
    const [px, py, pz] = cell.pick.map((v) => v * 100);
    const ring = new THREE.Mesh(new THREE.RingGeometry(12, 16, 40), new THREE.MeshBasicMaterial({ color: 0x22d3ee, side: THREE.DoubleSide }));
    ring.position.set(px, py, pz + 0.7);
    this.staticGroup.add(ring);
    this.robot = new Robot(cell);
    this.extraGroup.add(this.robot.root);
    this.carriedMesh = this.makeBox();
    this.robot.carried.add(this.carriedMesh);
  }

  makeBox() {
    const holder = new THREE.Group();
    holder.add(new THREE.Mesh(this.unitBox, new THREE.MeshStandardMaterial({ roughness: 0.55, metalness: 0.05 })),
      new THREE.LineSegments(this.unitEdges, this.edgeMaterial));
    return holder;
  }

  colorOf(index) {
    return viridis((index ?? 0) / Math.max(1, this.total - 1));
  }

  resize() {
    if (!this.renderer) return;
    const width = this.canvas.clientWidth || 800;
    const height = this.canvas.clientHeight || 540;
    this.renderer.setSize(width, height, false);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  // -- what is where ---------------------------------------------------------------------------------
  // The boxes standing in the container after `frame` steps, each {p, index, collapsed}.
  boxesAt(frame) {
    const ep = this.episode;
    if (frame === this.frames && ep.final.length) {
      return ep.final.map((f) => ({ p: f.actual, index: f.actual.index ?? f.planned.index, collapsed: !f.in_place }));
    }
    if (frame === 0) return [];
    const step = ep.steps[frame - 1];
    if (step.poses) {
      const limit = THRESHOLDS[ep.dataset] ?? 7;
      return step.poses.map((p) => {
        const placedAt = this.indexOf.has(p.index) ? ep.steps[this.indexOf.get(p.index)].placement : null;
        const moved = placedAt ? center(p).distanceTo(center(placedAt)) > limit : false;
        return { p, index: p.index, collapsed: moved || (step.collapsed_boxes || []).includes(p.index) };
      });
    }
    const moved = new Set(step.collapsed_boxes || []);
    const out = [];
    for (let i = 0; i < frame; i += 1) {
      const s = ep.steps[i];
      if (!s.placement) continue;
      const index = s.placement.index ?? i;
      const collapsed = moved.has(index) || (step.collapsed && i === frame - 1 && !moved.size);
      out.push({ p: s.placement, index, collapsed });
    }
    return out;
  }

  // A box's pose from its track at `ms` into the step, or null before its first sample.
  trackPose(row, times, ms) {
    const first = row[1];
    const n = (row.length - 2) / 7;
    if (ms < times[first]) return null;
    const i = Math.min(bracket(times, ms), first + n - 1) - first;
    const j = Math.min(i + 1, n - 1);
    const ti = times[first + i];
    const tj = times[first + j];
    const f = j > i && tj > ti ? Math.min(1, Math.max(0, (ms - ti) / (tj - ti))) : 0;
    const at = (k, c) => row[2 + 7 * k + c];
    const pos = new THREE.Vector3(...[0, 1, 2].map((c) => (at(i, c) + f * (at(j, c) - at(i, c))) * TRACK_CM));
    const qa = new THREE.Quaternion(...[3, 4, 5, 6].map((c) => at(i, c) * TRACK_QUAT)).normalize();
    const qb = new THREE.Quaternion(...[3, 4, 5, 6].map((c) => at(j, c) * TRACK_QUAT)).normalize();
    return { pos, quat: qa.slerp(qb, f) };
  }

  stepSeconds(k) {
    return Math.max(MIN_STEP_S, this.durations[k - 1] || 0);
  }

  // Show position `u` of the time line (see the header comment).
  show(u) {
    const N = this.frames;
    u = Math.max(0, Math.min(N, Number.isFinite(u) ? u : 0));
    if (!this.timed) u = Math.round(u);
    this.u = u;
    const k = u <= 1e-9 ? 0 : Math.ceil(u - 1e-9);
    const f = k === 0 ? 1 : u - (k - 1);
    const step = k > 0 ? this.episode.steps[k - 1] : null;
    const during = step !== null && f < 1 - 1e-9 && this.durations[k - 1] > 0;
    const ms = during ? f * this.stepSeconds(k) * 1000 : null;
    this.slider.value = String(u);
    let phase = "";
    if (during && step.motion) {
      const current = step.motion.phases.find((p) => ms >= p[1] && ms < p[2]);
      phase = current ? current[0] : "";
    } else if (during && step.track) phase = "settle";
    this.root.dataset.frame = String(k);
    this.root.dataset.phase = phase;
    this.root.dataset.time = ms === null ? "" : String(Math.round(ms));
    this.el("label").textContent = `Step ${k} / ${N}`;
    let drawn = 0;
    if (this.renderer) drawn = this.draw(k, step, ms);
    this.root.dataset.boxes = String(drawn);
    this.showStepInfo(k, phase, ms);
    this.render();
  }

  draw(k, step, ms) {
    const during = ms !== null;
    const boxes = this.boxesAt(during ? k - 1 : k);
    const placing = step && step.placement ? step.placement.index : null;
    const motion = during && step.motion ? step.motion : null;
    const released = !motion || ms >= motion.grip[1];
    if (during && placing !== null && released && !boxes.some((b) => b.index === placing)) {
      const after = this.boxesAt(k).find((b) => b.index === placing);
      if (after) boxes.push({ ...after, collapsed: false });
    }
    const track = during && step.track ? step.track : null;
    const moving = new Map();
    if (track) for (const row of track.boxes) moving.set(row[0], row);
    const seen = new Set();
    for (const b of boxes) {
      let holder = this.boxes.get(b.index);
      if (!holder) {
        holder = this.makeBox();
        holder.userData.material = holder.children[0].material;
        holder.userData.material.color.copy(this.colorOf(b.index));
        this.boxes.set(b.index, holder);
        this.boxGroup.add(holder);
      }
      seen.add(b.index);
      holder.visible = true;
      holder.children[0].material = b.collapsed ? this.collapseMaterial : holder.userData.material;
      holder.children[1].material = !during && k < this.frames && b.index === placing ? this.currentEdgeMaterial : this.edgeMaterial;
      const rotation = boxRotation(b.p);
      const pose = moving.has(b.index) ? this.trackPose(moving.get(b.index), track.t, ms) : null;
      if (pose) {
        holder.position.copy(pose.pos);
        holder.quaternion.copy(boxRotation({ ...b.p, quaternion: pose.quat.toArray() }) || pose.quat);
      } else {
        holder.position.copy(center(b.p));
        holder.quaternion.copy(rotation || new THREE.Quaternion());
      }
      // Shrink by a hair so touching faces do not flicker.
      holder.scale.set(Math.max(0.1, b.p.length - 0.15), Math.max(0.1, b.p.width - 0.15), Math.max(0.1, b.p.height - 0.15));
    }
    for (const [index, holder] of this.boxes) if (!seen.has(index)) holder.visible = false;
    this.extraGroup.children.filter((c) => c !== (this.robot && this.robot.root)).forEach((c) => this.extraGroup.remove(c));
    this.drawRobot(k, step, ms);
    if (step && !step.placement && step.action) this.drawRejected(step, boxes);
    const path = step && step.tool_path && step.tool_path.length > 1;
    if (path) this.drawPath(step.tool_path);
    // Read by tests and handy in the console: what this frame shows.
    this.root.dataset.collapsed = String(boxes.filter((b) => b.collapsed).length);
    this.root.dataset.toolPath = path ? String(step.tool_path.length) : "0";
    return boxes.length;
  }

  // The arm: at its waiting pose between steps (the next box waiting on the conveyor), else along the
  // step's motion with the box on the cup while the suction is on.
  drawRobot(k, step, ms) {
    const robot = this.robot;
    if (!robot) return;
    const motion = ms !== null && step && step.motion ? step.motion : null;
    const upcoming = ms === null ? this.episode.steps[k] : null; // the next step's box waits at the pick
    const shown = motion ? step : upcoming && upcoming.motion ? upcoming : null;
    const carried = this.carriedMesh;
    carried.visible = false;
    this.root.dataset.suction = "off";
    if (shown) {
      const m = shown.motion;
      const [x, y, z, qx, qy, qz, qw] = m.carry;
      const box = shown.box;
      carried.position.set(x, y, z);
      carried.quaternion.set(qx, qy, qz, qw).normalize();
      carried.scale.set(Math.max(0.001, box.length - 0.15) / 100, Math.max(0.001, box.width - 0.15) / 100, Math.max(0.001, box.height - 0.15) / 100);
      const index = shown.placement ? shown.placement.index : this.episode.steps.indexOf(shown);
      carried.children[0].material.color.copy(this.colorOf(index));
      if (!motion || ms < m.grip[0]) {
        // Not yet grasped: the box sits on the conveyor where the cup will meet it.
        robot.setJoints(jointsAt(m, m.grip[0]));
        const world = carried.matrixWorld.clone();
        robot.setJoints(motion ? jointsAt(m, ms) : this.episode.cell.home);
        this.drawWaiting(world);
      } else if (ms < m.grip[1]) {
        robot.setJoints(jointsAt(m, ms));
        carried.visible = true;
        this.root.dataset.suction = "on";
      } else {
        robot.setJoints(jointsAt(m, ms));
      }
    } else {
      robot.setJoints(this.episode.cell.home);
    }
  }

  drawWaiting(matrix) {
    const copy = this.carriedMesh.clone();
    copy.visible = true;
    copy.matrixAutoUpdate = false;
    copy.matrix.copy(matrix);
    this.extraGroup.add(copy);
  }

  // A refused action (out of bounds, too high...): a red wireframe where the policy wanted the box.
  drawRejected(step, boxes) {
    const a = step.action;
    const l = a.orientation === 1 ? step.box.width : step.box.length;
    const w = a.orientation === 1 ? step.box.length : step.box.width;
    let z = 0;
    for (const b of boxes) {
      const p = b.p;
      if (p.x < a.x + l && a.x < p.x + p.length && p.y < a.y + w && a.y < p.y + p.width) z = Math.max(z, p.z + p.height);
    }
    const ghost = new THREE.LineSegments(this.unitEdges, new THREE.LineBasicMaterial({ color: COLLAPSE_COLOR }));
    ghost.position.set(a.x + l / 2, a.y + w / 2, z + step.box.height / 2);
    ghost.scale.set(l, w, step.box.height);
    this.extraGroup.add(ghost);
  }

  drawPath(points) {
    const key = points;
    if (this.pathKey !== key) {
      this.pathKey = key;
      this.pathMesh = new THREE.Group();
      const vectors = points.map(([x, y, z]) => new THREE.Vector3(x, y, z));
      const path = new THREE.CurvePath();
      for (let i = 1; i < vectors.length; i += 1) {
        if (vectors[i].distanceTo(vectors[i - 1]) > 1e-6) path.add(new THREE.LineCurve3(vectors[i - 1], vectors[i]));
      }
      if (path.curves.length) {
        const segments = Math.min(600, Math.max(16, path.curves.length * 4));
        this.pathMesh.add(new THREE.Mesh(new THREE.TubeGeometry(path, segments, 0.8, 6, false),
          new THREE.MeshStandardMaterial({ color: PATH_COLOR, emissive: 0x3b0764, transparent: true, opacity: 0.8 })));
        for (const end of [vectors[0], vectors[vectors.length - 1]]) {
          const dot = new THREE.Mesh(new THREE.SphereGeometry(2.2, 16, 12), new THREE.MeshStandardMaterial({ color: PATH_COLOR }));
          dot.position.copy(end);
          this.pathMesh.add(dot);
        }
      }
    }
    this.extraGroup.add(this.pathMesh);
  }

  render() {
    if (this.renderer) this.renderer.render(this.scene, this.camera);
  }

  // -- playing -----------------------------------------------------------------------------------------
  stepBy(delta) {
    this.stop();
    this.show(delta > 0 ? Math.floor(this.u + 1e-9) + 1 : Math.ceil(this.u - 1e-9) - 1);
  }

  togglePlay() {
    if (this.playing) { this.stop(); return; }
    if (this.u >= this.frames) this.show(0);
    this.playing = true;
    this.el("play").textContent = "Pause";
    let last = performance.now();
    // The play position runs continuously; an episode with nothing timed shows it a whole step at a time.
    let u = this.u;
    const tick = (now) => {
      if (!this.playing) return;
      let left = ((now - last) / 1000) * this.speed;
      last = now;
      // Advance through as many steps as the elapsed time covers, each at its own duration.
      while (left > 0 && u < this.frames) {
        const k = Math.floor(u + 1e-9) + 1;
        const seconds = this.stepSeconds(k);
        const rest = (k - u) * seconds;
        if (left < rest) { u += left / seconds; left = 0; } else { u = k; left -= rest; }
      }
      const shown = this.timed ? u : Math.floor(u + 1e-9);
      if (shown !== this.u) this.show(shown);
      if (u >= this.frames) this.stop(); else this.raf = requestAnimationFrame(tick);
    };
    this.raf = requestAnimationFrame(tick);
  }

  stop() {
    this.playing = false;
    if (this.raf) cancelAnimationFrame(this.raf);
    this.raf = null;
    this.el("play").textContent = "Play";
  }

  // -- figures beside the view -------------------------------------------------------------------------
  showStepInfo(frame, phase, ms) {
    setKV(this.el("step-info"), stepRows(this.episode, frame));
    const { text, alarm } = overlayText(this.episode, frame, phase, ms, this.root.dataset.suction === "on");
    this.overlay.classList.toggle("collapse", alarm);
    this.overlay.textContent = text;
  }

  showEpisodeInfo() {
    setKV(this.el("episode-info"), episodeRows(this.episode));
  }

  // For tests and the console: the TCP in the container frame (cm), or null without a robot.
  tcpWorld() {
    return this.robot ? this.robot.tcpWorld().toArray() : null;
  }
}

export function mountReplay(root, episodes) {
  if (!episodes || !episodes.length) {
    root.querySelector('[data-role="overlay"]').textContent = "This trace holds no episode.";
    return null;
  }
  const replay = new Replay(root, episodes);
  window.robobppReplay = replay; // handle for tests and the console
  return replay;
}

const root = document.querySelector("[data-replay]");
const data = document.getElementById("trace-data");
if (root && data) mountReplay(root, JSON.parse(data.textContent).episodes);
