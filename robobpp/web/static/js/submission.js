// Submission page: live progress while the evaluation runs, and the two charts (Chart.js, vendored).
(function () {
  const data = JSON.parse(document.getElementById("submission-data").textContent);
  const PALETTE = ["#2563eb", "#16a34a", "#f59e0b", "#dc2626", "#7c3aed", "#0891b2", "#db2777", "#65a30d", "#ea580c"];

  function charts() {
    if (typeof Chart === "undefined") return;
    Chart.defaults.font.family = getComputedStyle(document.body).fontFamily;
    document.querySelectorAll("canvas[data-radar]").forEach((canvas) => {
      const group = data.radar[Number(canvas.dataset.radar)];
      new Chart(canvas, {
        type: "radar",
        // Long metric names on two lines, so the labels around the chart stay clear of each other.
        data: {
          labels: group.labels.map((l) => (l.length > 12 && l.includes(" ") ? l.split(" ") : l)),
          datasets: group.series.map((s, i) => ({
            label: s.label, data: s.values, borderColor: PALETTE[i % PALETTE.length],
            backgroundColor: PALETTE[i % PALETTE.length] + "22", pointRadius: 3, borderWidth: 2,
          })),
        },
        options: { maintainAspectRatio: false, animation: false,
          // Ring labels sit on the vertical axis, under the top metric's label: the outer ring (1) and the
          // centre (0) go unlabelled and the metric labels keep a gap, so the two never overlap.
          scales: { r: { min: 0, max: 1,
                         ticks: { stepSize: 0.25, showLabelBackdrop: false, color: "#64748b", font: { size: 10 },
                                  callback: (v) => (v > 0 && v < 1 ? v.toFixed(2) : "") },
                         pointLabels: { font: { size: 12 }, padding: 12 } } },
          plugins: { legend: { position: "bottom" } } },
      });
    });
    const util = document.getElementById("util-chart");
    if (util) {
      new Chart(util, {
        type: "bar",
        data: { labels: data.utilization.labels,
          datasets: [{ label: "episodes", data: data.utilization.counts, backgroundColor: "#60a5fa", borderColor: "#2563eb", borderWidth: 1 }] },
        options: { maintainAspectRatio: false, animation: false, plugins: { legend: { display: false } },
          scales: { x: { title: { display: true, text: "space utilisation" } },
                    y: { beginAtZero: true, ticks: { precision: 0 }, title: { display: true, text: "episodes" } } } },
      });
    }
  }

  function follow() {
    if (!data.active) return;
    const text = document.querySelector('[data-role="progress-text"]');
    const bar = document.querySelector('[data-role="progress-bar"]');
    const badge = document.querySelector('[data-role="status"]');
    const live = document.querySelector('[data-role="live"]');
    async function poll() {
      try {
        const response = await fetch(data.status_url, { headers: { Accept: "application/json" }, cache: "no-store" });
        if (!response.ok) throw new Error(`HTTP ${response.status}`);
        const s = await response.json();
        const p = s.progress;
        let line = `${p.episodes_done} of ${p.episodes_total} episodes finished`;
        if (p.episodes_running) line += ` · ${p.episodes_running} running`;
        if (p.episodes_failed) line += ` · ${p.episodes_failed} failed`;
        if (p.phase) line += ` · now: ${p.phase}`;
        text.textContent = line;
        bar.style.width = `${p.episodes_total ? (100 * p.episodes_done) / p.episodes_total : 0}%`;
        badge.textContent = s.status;
        badge.className = `badge status-${s.status}`;
        const queue = document.querySelector('[data-role="queue"]');
        if (queue && !s.queue) queue.remove();
        else if (queue && s.queue.position) {
          let q = `Queued: position ${s.queue.position} in the fair-share order (${s.queue.ahead} episode${s.queue.ahead === 1 ? "" : "s"} of others or earlier submissions first, ${s.queue.running} running now)`;
          const eta = s.queue.estimated_start_s;
          // worded as robobpp.schemas.start_estimate_text words it on the server
          if (eta !== null) {
            const about = eta < 60 ? `${Math.max(1, Math.ceil(eta))} s` : eta < 3600 ? `${Math.ceil(eta / 60)} min` : `${(eta / 3600).toFixed(1)} h`;
            q += `; estimated start in about ${about} (an estimate from the running episodes' progress)`;
          }
          queue.textContent = q + ".";
        }
        if (s.status !== "queued" && s.status !== "running") {
          live.textContent = "Finished — loading the results…";
          window.setTimeout(() => window.location.reload(), 600);
          return;
        }
      } catch (err) {
        if (live) live.textContent = `Lost contact with the server (${err.message}); retrying…`;
      }
      window.setTimeout(poll, 2000);
    }
    window.setTimeout(poll, 1000);
  }

  charts();
  follow();
})();
