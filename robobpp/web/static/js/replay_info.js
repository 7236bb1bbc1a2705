// The figures beside the replay's 3D view: this step, the episode, and the line over the canvas.
// Plain text only: everything reaches the page through textContent, never parsed as HTML.

export const TERMINATION_TEXT = {
  completed: "every box was placed",
  no_feasible_placement: "no feasible placement",
  out_of_bounds: "footprint outside the container",
  too_high: "box top above the container",
  collapse: "a collapse (a box moved beyond the threshold)",
  policy_error: "policy error",
  policy_timeout: "policy timeout",
  protocol_violation: "protocol violation",
  episode_timeout: "episode time budget exceeded",
  failed_grasp: "suction grasp failed",
  place_plan_failed: "the robot could not start its place move",
  dangerous_operations: "third dangerous operation",
  invalid_action: "invalid action",
};
const PHASE_TEXT = { pick: "pick", transfer: "transfer", retreat: "retreat" };

export function fmt(value, digits = 3, unit = "") {
  if (value === null || value === undefined || !Number.isFinite(value)) return "—";
  const text = value.toFixed(digits);
  return `${/^-0(\.0+)?$/.test(text) ? text.slice(1) : text}${unit}`;
}

export function setKV(dl, rows) {
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

// Rows of the "This step" panel after `frame` steps.
export function stepRows(ep, frame) {
  const frames = ep.steps.length;
  if (frame === 0) return [["Step", `0 of ${frames}`], ["State", "empty container"]];
  const s = ep.steps[frame - 1];
  const p = s.placement;
  const rows = [
    ["Step", `${frame} of ${frames} (box #${s.step ?? frame - 1})`],
    ["Box (cm)", `${fmt(s.box.length, 0)} × ${fmt(s.box.width, 0)} × ${fmt(s.box.height, 0)}`],
    ["Position (cm)", p ? `x ${fmt(p.x, 1)}, y ${fmt(p.y, 1)}, z ${fmt(p.z, 1)}` : "not placed"],
    ["Orientation", p ? (p.orientation === 1 ? "1 (rotated 90°)" : "0 (length along x)") : "—"],
    ["Decision time", fmt(s.decision_time === null ? null : s.decision_time * 1000, 2, " ms")],
  ];
  if (s.static_stability !== null) rows.push(["Static stability", fmt(s.static_stability, 3)]);
  if (s.trajectory_length_m !== null) rows.push(["Tool path", fmt(s.trajectory_length_m, 2, " m")]);
  if (s.motion) rows.push(["Operation", `${fmt((s.motion.grip[1] - s.motion.grip[0]) / 1000, 2, " s")} grasp to release`]);
  if (s.dangerous !== null) rows.push(["Dangerous", s.dangerous ? "yes" : "no", s.dangerous ? "bad" : ""]);
  if (s.collapsed) rows.push(["Collapse", "yes — a box moved beyond the threshold", "bad"]);
  if (s.termination) rows.push(["Ended", TERMINATION_TEXT[s.termination] || s.termination, "bad"]);
  return rows;
}

// The line over the canvas, and whether it raises the alarm (collapse, danger, an early end).
export function overlayText(ep, frame, phase, ms, suction) {
  const frames = ep.steps.length;
  if (frame === 0) return { text: `${ep.dataset} · ${ep.setting} — empty container`, alarm: false };
  const s = ep.steps[frame - 1];
  let text = `Step ${frame} / ${frames}`;
  if (ms !== null && phase) {
    text += ` — ${PHASE_TEXT[phase] || phase}${suction ? " · suction on" : ""} · ${fmt(ms / 1000, 2, " s")}`;
  } else if (frame === frames) text += ` — final state: ${TERMINATION_TEXT[ep.termination] || ep.termination}`;
  if (s.dangerous) text += " — dangerous operation";
  const fallen = s.collapsed && (ms === null || phase === "settle" || phase === "retreat");
  // Said once: the final state of an episode that a collapse ended already names it.
  const saidEnded = frame === frames && ms === null && ep.termination === "collapse";
  if (fallen && !saidEnded) text += " — boxes collapsed";
  const ended = s.termination && s.termination !== "completed" && ms === null;
  return { text, alarm: Boolean(fallen || s.dangerous || ended) };
}

// Rows of the "Episode" panel.
export function episodeRows(ep) {
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
  return rows;
}
