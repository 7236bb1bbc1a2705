// Sortable tables: click a header to sort by that column, click again to reverse.
// The table is rendered sorted by rank on the server, so it reads fine with JavaScript off; this only adds
// buttons to the headers marked `data-sort` ("num" or "text"). Cells may carry `data-value` (the raw number);
// empty values always sort last.
(function () {
  function cellValue(row, index, kind) {
    const cell = row.cells[index];
    if (!cell) return null;
    const raw = cell.dataset.value !== undefined ? cell.dataset.value : cell.textContent.trim();
    if (raw === "" || raw === "—") return null;
    if (kind === "num") {
      const n = Number(raw);
      return Number.isFinite(n) ? n : null;
    }
    return raw.toLocaleLowerCase();
  }

  function sortBy(table, th, index, kind) {
    const body = table.tBodies[0];
    const ascending = th.getAttribute("aria-sort") !== "ascending";
    table.querySelectorAll("th[aria-sort]").forEach((other) => other.removeAttribute("aria-sort"));
    th.setAttribute("aria-sort", ascending ? "ascending" : "descending");
    const rows = Array.from(body.rows).map((row, i) => ({ row, i, v: cellValue(row, index, kind) }));
    rows.sort((a, b) => {
      if (a.v === null && b.v === null) return a.i - b.i;
      if (a.v === null) return 1;
      if (b.v === null) return -1;
      const c = a.v < b.v ? -1 : a.v > b.v ? 1 : 0;
      return (ascending ? c : -c) || a.i - b.i;
    });
    body.append(...rows.map((r) => r.row));
  }

  function init(table) {
    const headRow = table.tHead.rows[table.tHead.rows.length - 1];
    Array.from(headRow.cells).forEach((th, index) => {
      const kind = th.dataset.sort;
      if (!kind) return;
      const button = document.createElement("button");
      button.type = "button";
      button.append(...Array.from(th.childNodes));
      th.append(button);
      th.classList.add("sortable");
      button.addEventListener("click", () => sortBy(table, th, index, kind));
    });
  }

  document.querySelectorAll("table[data-sortable]").forEach(init);
})();
