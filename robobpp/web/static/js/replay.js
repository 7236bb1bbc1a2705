// robobpp episode replay: a three.js view of a trace, step by step.
//
// The page holds the markup (templates/_replay.html) and the trace as JSON in <script id="trace-data">
// (already checked and trimmed by robobpp/web/trace.py). Frame k shows the container after k steps:
// frame 0 is empty, the last frame is the final state (actual poses, boxes out of place in red).
// The same file runs on the server's replay page and in `robobpp view`'s offline page.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

// Viridis from a quarter up (its darkest end hides edges and shading), then interpolated in sRGB.
const VIRIDIS = ["#3b528b", "#2c728e", "#21918c", "#27ad81", "#5ec962", "#aadc32", "#fde725"]
  .map((hex) => { const c = new THREE.Color(hex); return [c.r, c.g, c.b]; });
const COLLAPSE_COLOR = new THREE.Color("#e11d48");
const PATH_COLOR = new THREE.Color("#f97316");
// Collapse thresholds of BENCHMARK.md §2 (cm): a box displaced further than this is drawn as collapsed.
const THRESHOLDS = { repetitive: 7, diverse: 4, longboard: 7 };
const TERMINATION_TEXT = {
  completed: "every box was placed",
  no_feasible_placement: "no feasible placement",
  out_of_bounds: "footprint outside the container",
  too_high: "box top above the container",
  collapse: "collapse",
  policy_error: "policy error",
  policy_timeout: "policy timeout",
  protocol_violation: "protocol violation",
  episode_timeout: "episode time budget exceeded",
  grasp_failed: "suction grasp failed",
  invalid_action: "invalid action",
};

function viridis(t) {
  const x = Math.min(1, Math.max(0, t)) * (VIRIDIS.length - 1);
  const i = Math.min(VIRIDIS.length - 2, Math.floor(x));
  const f = x - i;
  const a = VIRIDIS[i];
  const b = VIRIDIS[i + 1];
  return new THREE.Color(a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f);
}

function fmt(value, digits = 3, unit = "") {
  if (value === null || value === undefined || !Number.isFinite(value)) return "—";
  const text = value.toFixed(digits);
  return `${/^-0(\.0+)?$/.test(text) ? text.slice(1) : text}${unit}`;
}

function setKV(dl, rows) {
  dl.replaceChildren();
  for (const [key, value, cls] of rows) {
    const dt = document.createElement("dt");
    dt.textContent = key;
    const dd = document.createElement("dd");
    dd.textContent = value; // textContent: trace strings are never parsed as HTML
    if (cls) dd.className = cls;
    dl.append(dt, dd);
  }
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
    this.frame = 0;
    this.timer = null;
    this.unitBox = new THREE.BoxGeometry(1, 1, 1);
    this.unitEdges = new THREE.EdgesGeometry(this.unitBox);
    this.edgeMaterial = new THREE.LineBasicMaterial({ color: 0x1e293b, transparent: true, opacity: 0.55 });
    this.currentEdgeMaterial = new THREE.LineBasicMaterial({ color: 0x000000 });
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
      this.renderer = new THREE.WebGLRenderer({ canvas: this.canvas, antialias: true, alpha: true });
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
    this.camera = new THREE.PerspectiveCamera(38, 1, 1, 20000);
    this.camera.up.set(0, 0, 1);
    this.controls = new OrbitControls(this.camera, this.canvas);
    this.controls.enableDamping = false;
    this.controls.addEventListener("change", () => this.render());
    this.staticGroup = new THREE.Group();
    this.boxGroup = new THREE.Group();
    this.scene.add(this.staticGroup, this.boxGroup);
    new ResizeObserver(() => this.resize()).observe(this.canvas);
  }

  bindControls() {
    this.el("first").addEventListener("click", () => this.setFrame(0));
    this.el("last").addEventListener("click", () => this.setFrame(this.frames));
    this.el("prev").addEventListener("click", () => this.setFrame(this.frame - 1));
    this.el("next").addEventListener("click", () => this.setFrame(this.frame + 1));
    this.el("play").addEventListener("click", () => this.togglePlay());
    this.slider.addEventListener("input", () => { this.stop(); this.setFrame(Number(this.slider.value)); });
    document.addEventListener("keydown", (event) => {
      const tag = event.target && event.target.tagName;
      if (tag === "SELECT" || tag === "TEXTAREA" || (tag === "INPUT" && event.target !== this.slider)) return;
      if (event.key === "ArrowRight") { this.setFrame(this.frame + 1); event.preventDefault(); }
      else if (event.key === "ArrowLeft") { this.setFrame(this.frame - 1); event.preventDefault(); }
      else if (event.key === " " && event.target === document.body) { this.togglePlay(); event.preventDefault(); }
    });
  }

  load(index) {
    this.stop();
    this.episode = this.episodes[index];
    this.frames = this.episode.steps.length;
    this.slider.max = String(this.frames);
    this.indexOf = new Map();
    this.episode.steps.forEach((s, i) => {
      if (s.placement && s.placement.index !== null && s.placement.index !== undefined) this.indexOf.set(s.placement.index, i);
    });
    this.total = Math.max(1, this.frames);
    this.showEpisodeInfo();
    if (this.renderer) this.buildStatic();
    this.setFrame(this.frames);
  }

  buildStatic() {
    const { length: L, width: W, height: H } = this.episode.container;
    this.staticGroup.clear();
    const pallet = new THREE.Mesh(new THREE.BoxGeometry(L, W, 3), new THREE.MeshStandardMaterial({ color: 0xc9a57b, roughness: 0.9 }));
    pallet.position.set(L / 2, W / 2, -1.5);
    this.staticGroup.add(pallet);
    const outline = new THREE.LineSegments(new THREE.EdgesGeometry(new THREE.BoxGeometry(L, W, H)),
      new THREE.LineDashedMaterial({ color: 0x64748b, dashSize: 4, gapSize: 3 }));
    outline.position.set(L / 2, W / 2, H / 2);
    outline.computeLineDistances();
    this.staticGroup.add(outline);
    const size = Math.max(L, W) * 3;
    const grid = new THREE.GridHelper(size, 30, 0xb8c2cf, 0xd5dce4);
    grid.rotation.x = Math.PI / 2;
    grid.position.set(L / 2, W / 2, -3.05);
    this.staticGroup.add(grid);
    const axes = new THREE.AxesHelper(Math.min(L, W) * 0.25);
    axes.position.set(0, 0, 0.2);
    this.staticGroup.add(axes);
    // Frame the container's bounding sphere from the front-left, a little above.
    const radius = 0.5 * Math.hypot(L, W, H);
    const distance = (1.08 * radius) / Math.sin(THREE.MathUtils.degToRad(this.camera.fov / 2));
    const direction = new THREE.Vector3(-0.55, -0.8, 0.62).normalize();
    const target = new THREE.Vector3(L / 2, W / 2, H * 0.42);
    this.camera.position.copy(target).addScaledVector(direction, distance);
    this.controls.target.copy(target);
    this.controls.update();
    this.resize();
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

  drawBoxes(frame) {
    this.boxGroup.clear();
    const boxes = this.boxesAt(frame);
    const current = frame > 0 ? this.episode.steps[frame - 1] : null;
    const currentIndex = current && current.placement ? current.placement.index : null;
    for (const b of boxes) {
      const color = b.collapsed ? COLLAPSE_COLOR : viridis((b.index ?? 0) / Math.max(1, this.total - 1));
      const material = new THREE.MeshStandardMaterial({ color, roughness: 0.55, metalness: 0.05 });
      if (b.collapsed) material.emissive = new THREE.Color(0x5b0a1c);
      const mesh = new THREE.Mesh(this.unitBox, material);
      const isCurrent = frame < this.frames && b.index === currentIndex;
      const edges = new THREE.LineSegments(this.unitEdges, isCurrent ? this.currentEdgeMaterial : this.edgeMaterial);
      const holder = new THREE.Group();
      holder.add(mesh, edges);
      holder.position.copy(center(b.p));
      const rotation = boxRotation(b.p);
      if (rotation) holder.quaternion.copy(rotation);
      // Shrink by a hair so touching faces do not flicker.
      holder.scale.set(Math.max(0.1, b.p.length - 0.15), Math.max(0.1, b.p.width - 0.15), Math.max(0.1, b.p.height - 0.15));
      this.boxGroup.add(holder);
    }
    if (current && !current.placement && current.action) this.drawRejected(current, boxes);
    const path = current && current.tool_path && current.tool_path.length > 1;
    if (path) this.drawPath(current.tool_path);
    // Read by tests and handy in the console: what this frame shows.
    this.root.dataset.collapsed = String(boxes.filter((b) => b.collapsed).length);
    this.root.dataset.toolPath = path ? String(current.tool_path.length) : "0";
    return boxes.length;
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
    this.boxGroup.add(ghost);
  }

  drawPath(points) {
    const vectors = points.map(([x, y, z]) => new THREE.Vector3(x, y, z));
    const path = new THREE.CurvePath();
    for (let i = 1; i < vectors.length; i += 1) {
      if (vectors[i].distanceTo(vectors[i - 1]) > 1e-6) path.add(new THREE.LineCurve3(vectors[i - 1], vectors[i]));
    }
    if (!path.curves.length) return;
    const segments = Math.min(600, Math.max(16, path.curves.length * 4));
    const tube = new THREE.Mesh(new THREE.TubeGeometry(path, segments, 1.2, 6, false),
      new THREE.MeshStandardMaterial({ color: PATH_COLOR, emissive: 0x7c2d12 }));
    this.boxGroup.add(tube);
    for (const end of [vectors[0], vectors[vectors.length - 1]]) {
      const dot = new THREE.Mesh(new THREE.SphereGeometry(3, 16, 12), new THREE.MeshStandardMaterial({ color: PATH_COLOR }));
      dot.position.copy(end);
      this.boxGroup.add(dot);
    }
  }

  setFrame(frame) {
    const f = Math.max(0, Math.min(this.frames, Math.round(frame)));
    this.frame = f;
    this.slider.value = String(f);
    this.el("label").textContent = `Step ${f} / ${this.frames}`;
    let drawn = 0;
    if (this.renderer) drawn = this.drawBoxes(f);
    this.root.dataset.frame = String(f);
    this.root.dataset.boxes = String(drawn);
    this.showStepInfo(f);
    this.render();
  }

  render() {
    if (this.renderer) this.renderer.render(this.scene, this.camera);
  }

  togglePlay() {
    if (this.timer) { this.stop(); return; }
    if (this.frame >= this.frames) this.setFrame(0);
    this.el("play").textContent = "Pause";
    this.timer = window.setInterval(() => {
      if (this.frame >= this.frames) { this.stop(); return; }
      this.setFrame(this.frame + 1);
    }, 220);
  }

  stop() {
    if (this.timer) window.clearInterval(this.timer);
    this.timer = null;
    this.el("play").textContent = "Play";
  }

  showStepInfo(frame) {
    const dl = this.el("step-info");
    const ep = this.episode;
    this.overlay.classList.remove("collapse");
    if (frame === 0) {
      setKV(dl, [["Step", `0 of ${this.frames}`], ["State", "empty container"]]);
      this.overlay.textContent = `${ep.dataset} · ${ep.setting} — empty container`;
      return;
    }
    const s = ep.steps[frame - 1];
    const p = s.placement;
    const rows = [
      ["Step", `${frame} of ${this.frames} (box #${s.step ?? frame - 1})`],
      ["Box (cm)", `${fmt(s.box.length, 0)} × ${fmt(s.box.width, 0)} × ${fmt(s.box.height, 0)}`],
      ["Position (cm)", p ? `x ${fmt(p.x, 1)}, y ${fmt(p.y, 1)}, z ${fmt(p.z, 1)}` : "not placed"],
      ["Orientation", p ? (p.orientation === 1 ? "1 (rotated 90°)" : "0 (length along x)") : "—"],
      ["Decision time", fmt(s.decision_time === null ? null : s.decision_time * 1000, 2, " ms")],
    ];
    if (s.static_stability !== null) rows.push(["Static stability", fmt(s.static_stability, 3)]);
    if (s.trajectory_length_m !== null) rows.push(["Tool path", fmt(s.trajectory_length_m, 2, " m")]);
    if (s.dangerous !== null) rows.push(["Dangerous", s.dangerous ? "yes" : "no", s.dangerous ? "bad" : ""]);
    if (s.collapsed) rows.push(["Collapse", "yes — a box moved beyond the threshold", "bad"]);
    if (s.termination) rows.push(["Ended", TERMINATION_TEXT[s.termination] || s.termination, "bad"]);
    setKV(dl, rows);
    let text = `Step ${frame} / ${this.frames}`;
    if (frame === this.frames) text += ` — final state: ${TERMINATION_TEXT[ep.termination] || ep.termination}`;
    if (s.collapsed) { text += " — collapse!"; this.overlay.classList.add("collapse"); }
    else if (s.termination && s.termination !== "completed") this.overlay.classList.add("collapse");
    this.overlay.textContent = text;
  }

  showEpisodeInfo() {
    const ep = this.episode;
    const pct = (v) => (v === null || v === undefined ? "—" : `${(v * 100).toFixed(1)}%`);
    const rows = [
      ["Dataset", ep.dataset || "—"], ["Setting", ep.setting || "—"], ["Policy", ep.policy || "—"],
      ["Group", ep.group ?? "—"], ["Boxes placed", `${ep.boxes_placed ?? "?"} of ${ep.boxes_total ?? "?"}`],
      ["Container (cm)", `${ep.container.length} × ${ep.container.width} × ${ep.container.height}`],
      ["Ended", `${TERMINATION_TEXT[ep.termination] || ep.termination}`],
    ];
    if (ep.termination_detail && ep.termination_detail !== TERMINATION_TEXT[ep.termination]
        && ep.termination !== "completed") rows.push(["Detail", ep.termination_detail]);
    const m = ep.metrics || {};
    if ("space_utilization" in m) rows.push(["Utilization", pct(m.space_utilization)]);
    if ("occupancy" in m) rows.push(["Occupancy", pct(m.occupancy)]);
    if ("local_stability" in m) rows.push(["Local stability", fmt(m.local_stability, 4, " m")]);
    if ("static_stability" in m) rows.push(["Static stability", fmt(m.static_stability, 3)]);
    if ("trajectory_length" in m) rows.push(["Trajectory", fmt(m.trajectory_length, 2, " m")]);
    setKV(this.el("episode-info"), rows);
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
