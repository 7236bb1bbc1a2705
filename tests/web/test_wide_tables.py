"""No table is cut, at a desktop width (1280 px) and a phone's (390 px).

Every table of every page either fits the window, or sits in a box that scrolls sideways inside the window
(scrolled to either end, the table's first and last columns are in view) and, while columns are out of view,
shows the line that says so. The pages come from the real server (Math and Physics boards, submissions,
account pages); the widest tables the server's settings do not produce here (an Execution board, the 3 × 3
overall grid) are rendered by the same templates and stylesheet from made-up figures.
"""

from __future__ import annotations

from typing import Any

import pytest

from robobpp.scoring.metrics import METRICS
from robobpp.web import environment, tables
from tests.web.conftest import ADMIN_TOKEN, Server, sign_in

WIDTHS = (1280, 390)

#: Per table: can all of it be seen? (the check is described in the module docstring)
REACH = """() => {
  const vw = document.documentElement.clientWidth;
  return Array.from(document.querySelectorAll('table')).filter((t) => t.offsetParent !== null).map((t, i) => {
    const name = t.id || `table ${i + 1}`;
    let box = t.parentElement;
    while (box !== document.body && getComputedStyle(box).overflowX === 'visible') box = box.parentElement;
    const r = t.getBoundingClientRect();
    if (box === document.body) {
      const fits = r.left >= -0.5 && r.right <= vw + 0.5;
      return {name, ok: fits, why: `no scroll box: table ${r.left.toFixed(0)}–${r.right.toFixed(0)} px, window ${vw}`};
    }
    if (!['auto', 'scroll'].includes(getComputedStyle(box).overflowX)) {
      const b = box.getBoundingClientRect();
      const fits = r.left >= b.left - 0.5 && r.right <= b.right + 0.5;
      return {name, ok: fits, why: `cut by a box that does not scroll (${getComputedStyle(box).overflowX})`};
    }
    const b = box.getBoundingClientRect();
    if (b.left < -0.5 || b.right > vw + 0.5) {
      return {name, ok: false, why: `its scroll box (${b.left.toFixed(0)}–${b.right.toFixed(0)} px) leaves the window (${vw})`};
    }
    const inner = () => {  // the box's visible area, inside its borders
      const s = box.getBoundingClientRect(), cs = getComputedStyle(box);
      return [s.left + parseFloat(cs.borderLeftWidth), s.left + parseFloat(cs.borderLeftWidth) + box.clientWidth];
    };
    const over = box.scrollWidth > box.clientWidth + 1;
    const start = box.scrollLeft;
    box.scrollLeft = box.scrollWidth;
    const lastIn = t.getBoundingClientRect().right <= inner()[1] + 1;
    box.scrollLeft = 0;
    const firstIn = t.getBoundingClientRect().left >= inner()[0] - 1;
    box.scrollLeft = start;
    const hint = box.previousElementSibling;
    const cue = !over || Boolean(hint && hint.dataset.role === 'scroll-hint' && !hint.hidden
                                 && hint.offsetParent !== null && hint.textContent.includes('→'));
    return {name, ok: lastIn && firstIn && cue, over,
            why: `scrolls: last column reachable ${lastIn}, first ${firstIn}, cue shown ${cue}`};
  });
}"""


def _check(page: Any, where: str, cut: list[str], scrolled: list[str]) -> None:
    tables_seen = page.evaluate(REACH)
    cut.extend(f"{where} {t['name']}: {t['why']}" for t in tables_seen if not t["ok"])
    scrolled.extend(f"{where} {t['name']}" for t in tables_seen if t.get("over"))
    wide = page.evaluate("() => document.documentElement.scrollWidth - document.documentElement.clientWidth")
    if wide > 1:
        cut.append(f"{where}: the page itself scrolls sideways by {wide} px")


@pytest.mark.parametrize("width", WIDTHS)
def test_no_table_is_cut_on_the_served_pages(server: Server, browser: Any, width: int) -> None:
    context = browser.new_context(viewport={"width": width, "height": 900})
    page = context.new_page()
    cut: list[str] = []
    scrolled: list[str] = []
    seen = 0
    try:
        public = [
            "/",
            "/?track=public&view=all",
            "/boards/repetitive/math",
            "/boards/diverse/physics",
            "/boards/longboard/physics?view=all",
            "/datasets",
            "/protocol",
            "/reproduction",
            "/?protocol=paper",
            "/boards/diverse/physics?protocol=paper",
            f"/submissions/{server.ids['public']}",
        ]
        signed = ["/account", "/operator", "/submit", f"/submissions/{server.ids['hostile']}"]
        for path in public:
            page.goto(server.url + path)
            seen += page.locator("table").count()
            _check(page, f"{width} px {path}", cut, scrolled)
        sign_in(page, server, ADMIN_TOKEN)
        for path in signed:
            page.goto(server.url + path)
            seen += page.locator("table").count()
            _check(page, f"{width} px {path} (operator)", cut, scrolled)
    finally:
        context.close()
    assert seen >= 10, seen
    assert not cut, "\n".join(cut)
    if width == 390:  # the check of a scrolling table ran, with its cue
        assert any("/boards/diverse/physics" in s for s in scrolled), scrolled


def _execution_board() -> dict[str, Any]:
    keys = [m.key for m in METRICS]
    entries = [
        {
            "rank": i + 1,
            "rank_low": 1,
            "rank_high": 4,
            "score": 0.9 - 0.1 * i,
            "score_low": 0.41,
            "score_high": 0.97,
            "stable": 0.61,
            "stable_low": 0.55,
            "stable_high": 0.66,
            "submission_id": i + 1,
            "name": f"a-rather-long-policy-name-{i} v12",
            "participant": "participant-with-a-long-name",
            "baseline": i % 2 == 0,
            "metrics": {k: 0.123456 + 0.01 * i for k in keys},
            "intervals": {k: [0.1, 0.2] for k in keys},
            "normalized": {k: 0.5 for k in keys},
            "extras": {"pph": 612.0, "boxes_placed_mean": 41.5, "episodes": 30},
        }
        for i in range(6)
    ]
    return {
        "dataset": "longboard",
        "setting": "execution",
        "entries": entries,
        "unranked": [],
        "total": 6,
        "anchors": "anchors-v1",
        "confidence": 0.95,
        "groups": 30,
        "resamples": 1000,
    }


def _grid() -> dict[str, Any]:
    settings, datasets = ["math", "physics", "execution"], ["repetitive", "diverse", "longboard"]
    cell = {
        "score": 0.734,
        "score_low": 0.512,
        "score_high": 0.998,
        "rank": 12,
        "rank_low": 3,
        "rank_high": 17,
    }
    rows = [
        {
            "submission_id": i + 1,
            "name": f"a-rather-long-policy-name-{i} v12",
            "participant": "participant-x",
            "baseline": False,
            "status": "ranked",
            "mean": 0.5,
            "mean_low": 0.412,
            "mean_high": 0.588,
            "stable": 0.61,
            "stable_low": 0.55,
            "stable_high": 0.66,
            "rank": i + 1,
            "rank_low": 1,
            "rank_high": 9,
            "cells": {f"{s}/{d}": cell for s in settings for d in datasets},
        }
        for i in range(6)
    ]
    return {
        "settings": settings,
        "datasets": datasets,
        "rows": rows,
        "apart": [],
        "apart_total": 0,
        "total": 6,
    }


@pytest.mark.parametrize("width", WIDTHS)
def test_no_table_is_cut_on_an_execution_board_and_the_full_grid(
    server: Server, browser: Any, width: int
) -> None:
    from robobpp.datasets import DATASETS
    from robobpp.scoring.scores import WEIGHTS
    from robobpp.server.site.session import Viewer

    common = {
        "root": server.url,
        "static": server.url + "/static",
        "viewer": Viewer(nonce="", admin=False),
        "csrf": "",
        "title": "t",
        "nav": "leaderboard",
        "track": "private",
        "view": "best",
        "top": tables.TOP,
    }
    board = _execution_board()
    pages = {
        "execution board": environment()
        .get_template("board.html")
        .render(
            **common,
            dataset=DATASETS["longboard"],
            setting="execution",
            table=tables.board_table(board),
            weights=WEIGHTS["execution"],
            pages=tables.pages(board, 1),
            board=board,
            protocol="closed",
            has_physical=False,
            other_boards=[],
        ),
        "3 × 3 grid": environment()
        .get_template("index.html")
        .render(
            **common,
            table=tables.grid_table(_grid()),
            datasets_info=DATASETS,
            pages=tables.pages(_grid(), 1),
            protocol="closed",
            has_physical=False,
        ),
    }
    context = browser.new_context(viewport={"width": width, "height": 900})
    cut: list[str] = []
    scrolled: list[str] = []
    try:
        page = context.new_page()
        for name, html in pages.items():
            page.set_content(html, wait_until="load")
            _check(page, f"{width} px {name}", cut, scrolled)
        if width == 1280:  # the figure that ranks the grid is in view before any scrolling (it was cut off)
            mean_right = page.evaluate(
                "() => document.querySelector('#overall [data-role=mean]').getBoundingClientRect().right"
            )
            assert mean_right <= page.evaluate(
                "() => document.querySelector('.table-wrap').getBoundingClientRect().right"
            )
    finally:
        context.close()
    assert not cut, "\n".join(cut)
    assert len(scrolled) == 2 or width == 1280, scrolled
