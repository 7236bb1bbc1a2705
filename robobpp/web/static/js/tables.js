// Wide tables: a line above each table that is wider than its box, saying how many columns are out of view
// and which way to scroll (overlay scroll bars are invisible until touched). The table scrolls without this
// script; the script only adds the words. Kept current on scrolling and on resizing.
(() => {
  const hidden = (wrap) => {
    const box = wrap.getBoundingClientRect();
    let left = 0, right = 0;
    const row = wrap.querySelector("tbody tr") || wrap.querySelector("tr");
    for (const cell of row ? row.cells : []) {
      const r = cell.getBoundingClientRect();
      if (r.right > box.right + 1) right += 1;
      else if (r.left < box.left - 1) left += 1;
    }
    return { left, right };
  };
  const update = (wrap, hint) => {
    const more = wrap.scrollWidth - wrap.clientWidth;
    if (more <= 1) {
      hint.hidden = true;
      wrap.dataset.overflow = "none";
      return;
    }
    const { left, right } = hidden(wrap);
    const cols = (n) => `${n} column${n === 1 ? "" : "s"}`;
    const parts = [];
    if (left) parts.push(`← ${cols(left)}`);
    if (right) parts.push(`${cols(right)} →`);
    hint.textContent = `Scroll sideways for more: ${parts.join(" · ") || "↔"}`;
    hint.hidden = false;
    wrap.dataset.overflow = wrap.scrollLeft >= more - 1 ? "end" : wrap.scrollLeft > 0 ? "middle" : "start";
  };
  for (const wrap of document.querySelectorAll(".table-wrap")) {
    const hint = document.createElement("p");
    hint.className = "scroll-hint";
    hint.dataset.role = "scroll-hint";
    hint.hidden = true;
    wrap.before(hint);
    const again = () => update(wrap, hint);
    wrap.addEventListener("scroll", again, { passive: true });
    if (window.ResizeObserver) new ResizeObserver(again).observe(wrap);
    else window.addEventListener("resize", again);
    again();
  }
})();
