"""The web layer's pure parts: trace checking, table models, dataset statistics, escaping, the docs example."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from robobpp.core import Box, ContainerSpec, EpisodeSpec
from robobpp.episode import run_episode
from robobpp.policies import load_policy
from robobpp.web import TEMPLATES_DIR, environment, fmt_metric, fmt_num, fmt_pct
from robobpp.web.dataset_stats import (
    boxplot_svg,
    five_numbers,
    nice_ticks,
    repeat_stats,
    summarise,
    weighted_quantiles,
)
from robobpp.web.tables import board_table, dense_top, grid_table, histogram, pages, radar_groups
from robobpp.web.trace import TraceError, episodes_from, read_trace, viewer_payload
from robobpp.web.viewer import render_standalone


def _box(rng: np.random.Generator, low: int, high: int) -> Box:
    """A 2 kg box of whole-centimetre sides drawn in [low, high)."""
    length, width, height = (float(v) for v in rng.integers(low, high, 3))
    return Box(length, width, height, 2.0)


def _episode(n: int = 15, seed: int = 1) -> dict:
    rng = np.random.default_rng(seed)
    boxes = tuple(_box(rng, 20, 60) for _ in range(n))
    spec = EpisodeSpec("repetitive", "train", 0, boxes, ContainerSpec(134, 125, 100), 7.0, 0)
    return run_episode(spec, load_policy("dbl"), "math").to_dict()


# ---- traces ------------------------------------------------------------------------------------------


def test_trace_accepts_one_episode_or_a_list() -> None:
    ep = _episode()
    single = episodes_from(ep)
    many = episodes_from({"policy": "dbl", "episodes": [ep, ep]})
    assert len(single) == 1 and len(many) == 2
    payload = single[0]
    assert payload["container"] == {"length": 134.0, "width": 125.0, "height": 100.0}
    assert len(payload["steps"]) == len(ep["steps"])
    assert len(payload["final"]) == ep["boxes_placed"]
    placed = [s for s in payload["steps"] if s["placement"]]
    assert placed[0]["placement"]["index"] == 0 and placed[0]["action"]["orientation"] in (0, 1)


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda e: e.update(container={"length": float("nan"), "width": 1, "height": 1}), "container.length"),
        (lambda e: e.update(container={"length": -5, "width": 1, "height": 1}), "must be positive"),
        (lambda e: e.update(container=None), "container must be an object"),
        (lambda e: e.update(steps="many"), "steps must be a list"),
        (
            lambda e: e["steps"][0].update(box={"length": "1", "width": 1, "height": 1}),
            "box.length must be a number",
        ),
        (lambda e: e["steps"][0]["placement"].update(x=1e12), "is out of range"),
        (lambda e: e["steps"][0]["placement"].update(quaternion=[0, 0, 0, 0]), "zero length"),
        (lambda e: e["steps"][0].update(extra={"tool_path_cm": [[1, 2]]}), "must be [x, y, z]"),
        (lambda e: e["final"][0].update(actual=[1, 2, 3]), "final[0].actual must be an object"),
    ],
)
def test_trace_refuses_hostile_fields_with_a_clear_message(mutate, message: str) -> None:
    ep = json.loads(json.dumps(_episode()))
    mutate(ep)
    with pytest.raises(TraceError, match=re.escape(message)):
        viewer_payload(ep)


def test_trace_file_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(TraceError, match="not valid JSON"):
        read_trace(bad)
    with pytest.raises(TraceError, match="cannot read"):
        read_trace(tmp_path / "missing.json")
    for data, message in (
        ([1, 2], "episode object"),
        ({"episodes": []}, "no episode"),
        ({"episodes": 3}, "list"),
    ):
        with pytest.raises(TraceError, match=message):
            episodes_from(data)


def test_trace_keeps_tool_path_and_collapse_extras() -> None:
    ep = _episode()
    ep["steps"][1]["extra"] = {"tool_path_m": [[0, 0, 2], [0.5, 0.5, 1.5]], "collapsed_boxes": [0, "x", 1]}
    ep["steps"][2]["extra"] = {"tool_path_cm": [[float(i), 0.0, 50.0] for i in range(5000)]}
    payload = viewer_payload(ep)
    assert payload["steps"][1]["tool_path"] == [[0.0, 0.0, 200.0], [50.0, 50.0, 150.0]]
    assert payload["steps"][1]["collapsed_boxes"] == [0, 1]
    thinned = payload["steps"][2]["tool_path"]
    assert len(thinned) == 2000 and thinned[0][0] == 0.0 and thinned[-1][0] == 4999.0


def test_standalone_viewer_escapes_trace_text() -> None:
    ep = _episode(5)
    ep["policy"] = "</script><script>alert(1)</script>"
    html = render_standalone(episodes_from(ep), source="<b>x</b>.json")
    assert "</script><script>alert(1)" not in html
    assert "<b>x</b>" not in html and "&lt;b&gt;x&lt;/b&gt;.json" in html
    assert "data:text/javascript;base64," in html  # three.js inlined: opens from disk


# ---- tables -------------------------------------------------------------------------------------------


def test_dense_top_shares_places_and_skips_missing() -> None:
    assert dense_top([0.5, 0.9, None, 0.9, 0.1, 0.3, 0.2], "up") == [2, 1, None, 1, None, 3, 4]
    assert dense_top([3.0, 1.0, 2.0], "down") == [3, 1, 2]
    assert dense_top([float("nan"), 1.0], "up") == [None, 1]


def _board() -> dict:
    entries = [
        {
            "rank": 1,
            "score": 0.9,
            "submission_id": 1,
            "name": "a",
            "participant": "p",
            "baseline": True,
            "metrics": {"space_utilization": 0.505, "occupancy": 0.8, "decision_time": 0.01},
            "intervals": {"space_utilization": [0.4553, 0.5551], "decision_time": [0.008, 0.0125]},
            "normalized": {"space_utilization": 1.0, "occupancy": 1.0, "decision_time": 0.0},
            "extras": {},
        },
        {
            "rank": 2,
            "score": 0.2,
            "submission_id": 2,
            "name": "<b>",
            "participant": "q",
            "baseline": False,
            "metrics": {"space_utilization": 0.4, "occupancy": 0.6, "decision_time": 0.001},
            "normalized": {"space_utilization": 0.0, "occupancy": 0.0, "decision_time": 1.0},
            "extras": {},
        },
    ]
    return {"dataset": "diverse", "setting": "math", "entries": entries}


def test_board_table_columns_and_places() -> None:
    table = board_table(_board())
    assert [c.key for c in table["columns"]] == ["space_utilization", "occupancy", "decision_time"]
    assert [c.arrow for c in table["columns"]] == ["↑", "↑", "↓"]
    first, second = table["rows"]
    assert first["cells"][0]["place"] == 1 and second["cells"][0]["place"] == 2
    # An interval is printed in its value's unit: a percentage under a percentage, seconds under seconds.
    assert fmt_metric(first["cells"][0]["value"], "space_utilization") == "50.5%"
    assert first["cells"][0]["ci"] == "45.5%–55.5%" and first["cells"][2]["ci"] == "0.0080–0.0125"
    assert second["cells"][0]["ci"] == ""
    assert first["cells"][2]["place"] == 2 and second["cells"][2]["place"] == 1  # lower time is better
    assert not table["has_pph"]


def test_a_later_page_highlights_the_columns_best_values_not_its_own() -> None:
    """Page 2 of a board shows a slice of its view: a value is marked only where it is among the view's best
    (``column_tops``), never because it is the best of the rows shown."""
    page = _board() | {
        "column_tops": {
            "score": [1.0, 0.95, 0.93, 0.9],
            "space_utilization": [0.7, 0.6, 0.505, 0.5],
            "occupancy": [0.99, 0.98, 0.97, 0.96],
            "decision_time": [0.0001, 0.0002, 0.0005, 0.001],
        }
    }
    first, second = board_table(page)["rows"]
    assert first["score_place"] == 4 and second["score_place"] is None
    assert [c["place"] for c in first["cells"]] == [3, None, None]
    assert [c["place"] for c in second["cells"]] == [None, None, 4]
    grid = {
        "settings": ["math"],
        "datasets": ["diverse"],
        "rows": [{"cells": {"math/diverse": {"score": 0.5, "rank": 60}}}],
        "column_tops": {"math/diverse": [0.9, 0.8, 0.7, 0.6]},
    }
    assert grid_table(grid)["rows"][0]["cells"][0]["place"] is None
    assert grid_table({**grid, "column_tops": {}})["rows"][0]["cells"][0]["place"] == 1  # tops unknown


def test_grid_table_and_radar() -> None:
    grid = {
        "settings": ["math"],
        "datasets": ["diverse", "longboard"],
        "rows": [
            {
                "submission_id": 2,
                "name": "b",
                "participant": "q",
                "baseline": False,
                "status": "ranked",
                "mean": 0.6,
                "mean_low": 0.5,
                "mean_high": 0.7,
                "rank": 1,
                "rank_low": 1,
                "rank_high": 2,
                "cells": {
                    "math/diverse": {"score": 0.2, "rank": 2},
                    "math/longboard": {"score": 1.0, "rank": 1},
                },
            },
        ],
        "apart": [
            {
                "submission_id": 1,
                "name": "a",
                "participant": "p",
                "baseline": True,
                "status": "partial",
                "boards": 1,
                "cells": {"math/diverse": {"score": 0.9, "rank": 1}},
            },
        ],
        "apart_total": 1,
    }
    table = grid_table(grid)
    assert table["keys"] == ["math/diverse", "math/longboard"]
    (b,) = table["rows"]
    (a,) = table["apart"]
    assert a["cells"][1]["score"] is None and a["mean"] is None and a["status"] == "partial"  # never a Mean
    assert b["cells"][1]["place"] == 1 and math.isclose(b["mean"], 0.6)
    assert b["rank_text"] == "1 (1–2)" and b["mean_ci"] == "0.500–0.700"
    runs = [{"dataset": "diverse", "setting": "math"}, {"dataset": "longboard", "setting": "math"}]
    board = _board()
    groups = radar_groups(runs, {("diverse", "math"): (board["entries"][1], len(board["entries"]))})
    assert len(groups) == 1 and groups[0]["labels"][0] == "Space Utilization"
    assert groups[0]["series"][0]["values"] == [0.0, 0.0, 1.0] and not groups[0]["single"]


def test_histogram_bins() -> None:
    h = histogram([0.0, 0.05, 0.5, 0.99, 1.0, float("nan")], bins=10)
    assert h["counts"] == [2, 0, 0, 0, 0, 1, 0, 0, 0, 2]
    assert h["labels"][0] == "0–10%"


def test_formatting() -> None:
    assert fmt_num(None) == "—" and fmt_num(float("inf")) == "—" and fmt_num(0.12345) == "0.123"
    assert fmt_pct(0.1234) == "12.3%" and fmt_metric(0.5, "occupancy") == "50.0%"
    assert fmt_metric(0.00012, "decision_time") == "0.0001"


def test_numbers_keep_fixed_decimals() -> None:
    """An Execution board showed "1.58e-05–0.0024" and the Reproduction page "+0.00082": fixed decimals
    per metric, never scientific notation; a positive value too small to show is not printed as zero."""
    from robobpp.web import fmt_signed
    from robobpp.web.tables import metric_span

    assert metric_span(1.58e-05, 0.0024, "decision_time") == "<0.0001–0.0024"
    assert (
        fmt_signed(0.00082) == "+0.001"
        and fmt_signed(-0.03) == "-0.030"
        and fmt_signed(0.00082, 4) == "+0.0008"
    )
    assert fmt_num(-0.00001) == "0.000" and fmt_num(0) == "0.000" and fmt_num(2e-9, 4) == "<0.0001"
    assert "e-" not in fmt_num(3e-7) + fmt_signed(-3e-7) + fmt_metric(3e-7, "decision_time")


# ---- datasets ------------------------------------------------------------------------------------------


def test_weighted_quantiles_follow_the_weights() -> None:
    values = np.array([1.0, 2.0, 3.0])
    assert weighted_quantiles(values, [0.5], None) == [2.0]
    assert weighted_quantiles(values, [0.5], np.array([0.1, 0.1, 0.8])) == [3.0]
    f = five_numbers(np.arange(101, dtype=float))
    assert (f.low, f.q1, f.median, f.q3, f.high) == (5.0, 25.0, 50.0, 75.0, 95.0)


def test_repeat_stats_and_summary() -> None:
    runs = np.array([[2, 2, 2], [2, 2, 2], [3, 3, 3], [3, 3, 3]], dtype=float)
    stats = repeat_stats([runs, runs[:1]])
    assert stats["repeat_rate"] == pytest.approx(2 / 3) and stats["distinct_per_group"] == 1.5
    summary = summarise(runs, None, [runs])
    assert summary["dims"]["length"].median == 2.5 and summary["entries"] == 4


def test_boxplot_geometry_is_ordered() -> None:
    plot = boxplot_svg([("L", five_numbers(np.arange(1.0, 80.0)), "#fff")], "cm")
    g = plot["glyphs"][0]
    assert plot["left"] <= g.low <= g.q1 <= g.median <= g.q3 <= g.high <= plot["right"]
    assert nice_ticks(47.4)[-1] >= 47.4 and nice_ticks(0) == [0.0, 1.0]


# ---- templates -----------------------------------------------------------------------------------------


def test_every_template_autoescapes() -> None:
    env = environment()
    for path in TEMPLATES_DIR.glob("*.html"):
        assert "|safe" not in path.read_text().replace(" ", ""), f"{path.name} marks data safe"
    html = env.get_template("board.html").render(
        root="",
        static="/static",
        title="t",
        nav="",
        dataset=__import__("robobpp.datasets").datasets.DATASETS["diverse"],
        setting="math",
        track="private",
        table=board_table(_board()),
        weights={"a": 1.0},
        top=4,
        other_boards=[],
        SETTING_TITLES={"math": "Math Pack"},
        view="best",
        pages=pages({"total": 2, "limit": 50}, 1),
        board={"anchors": "anchors-v1", "confidence": 0.95, "groups": 30, "resamples": 1000},
    )
    assert "<b>" not in html.split("<main>")[1] and "&lt;b&gt;" in html


def test_protocol_page_example_policy_really_packs() -> None:
    html = (TEMPLATES_DIR / "protocol.html").read_text()
    found = re.search(r"<pre><code>(from robobpp\.core.*?)</code></pre>", html, re.S)
    assert found is not None
    code = found.group(1)
    code = code.replace("&gt;", ">").replace("&lt;", "<").replace("&amp;", "&")
    namespace: dict = {}
    exec(compile(code, "protocol-example", "exec"), namespace)
    policy = namespace["LowestFirst"]()
    rng = np.random.default_rng(5)
    boxes = tuple(_box(rng, 20, 50) for _ in range(20))
    result = run_episode(
        EpisodeSpec("repetitive", "train", 0, boxes, ContainerSpec(134, 125, 100), 7.0, 0), policy, "math"
    )
    utilisation = result.metrics["space_utilization"]
    assert result.boxes_placed >= 5 and utilisation is not None and utilisation > 0.1
    # One API: the page shows exactly the policy of examples/policy_server.py.
    example = (Path(__file__).resolve().parents[2] / "examples" / "policy_server.py").read_text()
    assert code.strip() == example.split("# --- policy ---\n")[1].split("# --- end policy ---")[0].strip()


def test_view_cli_single_episode_and_bad_file(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from robobpp.cli import app, register_commands

    register_commands()
    one = tmp_path / "one.json"
    one.write_text(json.dumps(_episode(8)))
    out = tmp_path / "one.html"
    ok = CliRunner().invoke(app, ["view", str(one), "-o", str(out), "--no-open"])
    assert ok.exit_code == 0 and "1 episode(s)" in ok.output and out.stat().st_size > 100_000
    bad = tmp_path / "bad.json"
    bad.write_text('{"episodes": [{"container": {"length": "NaN"}}]}')
    refused = CliRunner().invoke(app, ["view", str(bad), "-o", str(out), "--no-open"])
    assert refused.exit_code == 2
    assert "episode 0.container.length must be a number" in refused.output


def test_view_cli_serves_the_viewer(tmp_path: Path) -> None:
    import socket
    import subprocess
    import sys
    import time

    import httpx

    trace = tmp_path / "out.json"
    trace.write_text(json.dumps({"episodes": [_episode(6)]}))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = "from robobpp.cli import main; main()"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "view", str(trace), "--no-open", "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                page = httpx.get(f"http://127.0.0.1:{port}/", timeout=5)
                break
            except httpx.TransportError:
                assert proc.poll() is None and time.monotonic() < deadline, "robobpp view did not start"
                time.sleep(0.2)
        assert page.status_code == 200 and 'id="trace-data"' in page.text
        assert httpx.get(f"http://127.0.0.1:{port}/static/js/replay.js", timeout=5).status_code == 200
    finally:
        proc.terminate()
        out = proc.communicate(timeout=20)[0].decode()
    assert f"http://127.0.0.1:{port}/" in out


def _board_page(entries: list, groups: int, protocol: str = "closed") -> str:
    from robobpp.datasets import DATASETS

    board = {**_board(), "entries": entries}
    return (
        environment()
        .get_template("board.html")
        .render(
            root="",
            static="/static",
            title="t",
            nav="",
            dataset=DATASETS["diverse"],
            setting="physics",
            track="private",
            table=board_table(board),
            weights={"a": 1.0},
            top=4,
            protocol=protocol,
            has_physical=True,
            other_boards=[
                ("repetitive", "math", "Repetitive · Math Pack"),
                ("diverse", "physics", "Diverse · Physics Pack"),
            ],
            SETTING_TITLES={"math": "Math Pack", "physics": "Physics Pack"},
            view="best",
            pages=pages({"total": len(entries), "limit": 50}, 1),
            board={"anchors": "anchors-v1", "confidence": 0.95, "groups": groups, "resamples": 1000},
        )
    )


def test_an_empty_board_says_so_plainly_and_links_boards_by_title() -> None:
    """An empty paper-protocol board read "interval over the board's 0 groups"; the "Other boards" links
    read "repetitive / math" where every title reads "Repetitive · Math Pack"."""
    empty = _board_page([], 0, "paper")
    assert "0 groups" not in empty and 'data-role="no-groups"' in empty
    assert "No completed entry on this board yet. Under the paper protocol" in empty
    full = _board_page(_board()["entries"], 30)
    assert "over the board's 30 groups" in full and 'data-role="no-groups"' not in full
    links = re.findall(r'<a href="/boards/[^"]+">([^<]+)</a>', full.split('data-role="other-boards"')[1])
    assert links == ["Repetitive · Math Pack", "Diverse · Physics Pack"]


def test_reproduction_tables_say_how_many_groups_are_behind_ours() -> None:
    """The groups behind "ours" were only in a tooltip (the demo compares 2 groups with the paper's 30)."""
    from robobpp.web.tables import reproduction_tables

    cell = {
        "setting": "physics",
        "metric": "space_utilization",
        "policy": "dbl",
        "paper": 0.5,
        "ours": 0.48,
        "diff": -0.02,
        "table": "T1",
    }
    data: dict[str, Any] = {
        "cells": [{**cell, "dataset": "diverse"}, {**cell, "dataset": "longboard"}],
        "runs": [
            {"setting": "physics", "dataset": d, "policy": "dbl", "groups": 2}
            for d in ("diverse", "longboard")
        ],
    }
    (table,) = reproduction_tables(data, {"dbl": "DBL"})
    assert table["groups"] == "2" and table["paper_groups"] == 30 and table["few_groups"]
    html = _reproduction_page({**data, "paper": "the paper"}, docs_url="")
    text = re.sub(r"<[^>]+>", "", html.split('data-role="groups"')[1].split("</p>")[0])
    assert "Ours: 2 groups per figure; the paper’s: 30." in text and "Far fewer groups" in text
    many = {**data, "runs": [{**r, "groups": 30} for r in data["runs"]]}
    assert (
        not reproduction_tables(many, {})[0]["few_groups"]
        and reproduction_tables(many, {})[0]["groups"] == "30"
    )


def _reproduction_page(data: dict, docs_url: str) -> str:
    from robobpp.paper import paper_tables
    from robobpp.web.tables import reproduction_scores, reproduction_tables

    titles = paper_tables().methods
    return (
        environment()
        .get_template("reproduction.html")
        .render(
            root="",
            static="/static",
            title="t",
            nav="",
            track="private",
            tables=reproduction_tables(data, titles),
            scores=reproduction_scores(data, titles),
            docs_url=docs_url,
            table_captions={},
            data=data,
            LOOP_TITLES={"paper": "paper protocol", "closed": "closed loop"},
            SETTING_TITLES={"physics": "Physics Pack"},
        )
    )


def _text(html: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html))


def test_reproduction_page_says_what_is_expected() -> None:
    """Each metric's table says why its figures differ and links the docs; Decision Time has no Spearman; the
    score comparison and the paper's other methods (paper-reported, compared with nothing) are shown."""
    from robobpp.reproduction import EXPECTED, compare

    figures = {
        ("physics", "diverse", p, m): v
        for p, (su, occ, dt, local, static) in {
            "dbl": (0.5, 0.8, 0.01, 0.002, 0.9),
            "hm": (0.4, 0.9, 0.02, 0.001, 1.0),
            "lsah": (0.6, 0.7, 0.03, 0.003, 0.8),
        }.items()
        for m, v in zip(
            ("space_utilization", "occupancy", "decision_time", "local_stability", "static_stability"),
            (su, occ, dt, local, static),
            strict=True,
        )
    }
    data = {**compare(figures).to_dict(), "runs": []}
    html = _reproduction_page(data, "https://docs.example/robobpp/")
    blocks = html.split("<h3>")[1:]
    timing = next(b for b in blocks if b.startswith("Decision Time"))
    assert 'data-role="not-compared"' in timing and "not compared" in _text(timing)
    utilization = next(b for b in blocks if b.startswith("Space Utilization"))
    assert "not compared" not in _text(utilization)
    for block, metric in ((utilization, "space_utilization"), (timing, "decision_time")):
        expected = EXPECTED[metric]
        assert expected.why.replace("'", "&#39;") in block
        assert f'<a href="https://docs.example/robobpp/{expected.doc}">{expected.doc}</a>' in block
    # the paper's other methods: its figures only, marked, and outside the Spearman (3 baselines, not 7)
    reported = re.findall(
        r'<tr data-policy="([^"]+)" class="paper-reported" data-paper-reported>', utilization
    )
    assert reported == ["ar2l", "tap-net++", "cdrl", "packe"]
    row = _text(utilization.split('data-policy="ar2l"')[1].split(">", 1)[1].split("</tr>")[0])
    assert "AR2L paper-reported" in row and row.count("—") == 2
    # the score comparison: Physics's weights without Decision Time, ours beside the paper's figures'
    score = html.split('data-role="score"')[1].split("</table>")[0]
    weights = _text(html.split('id="physics-score"')[1].split("</p>")[0])
    assert "Space Utilization 0.48 · Occupancy 0.21 · Local Stability 0.10 · Static Stability 0.21" in weights
    (scored,) = data["scores"]
    assert re.findall(r'<tr data-policy="([^"]+)">', score) == ["dbl", "hm", "lsah"]
    dbl = _text(score.split('data-policy="dbl">')[1].split("</tr>")[0]).split()
    assert dbl == ["DBL", f"{scored['ours'][0]:.3f}", f"{scored['paper'][0]:.3f}"]
    assert "ar2l" not in score
    # without a docs URL the references are paths, never a link to a page the server does not have
    plain = _reproduction_page(data, "")
    assert f"<code>{EXPECTED['decision_time'].doc}</code>" in plain and "docs.example" not in plain


def test_a_ranked_entry_without_its_rank_interval_yet_says_so() -> None:
    """Between two full computations an entry that arrived has a rank but no rank interval: the board marks
    it "(…)" and says why, where a bare "8" would read as a certain rank."""

    board = _board()
    board["entries"][0] |= {"rank_low": 1, "rank_high": 2}
    rows = board_table(board)["rows"]
    assert [r["rank_pending"] for r in rows] == [False, True]
    html = _board_page(board["entries"], 30)
    assert html.count('data-role="rank-pending"') == 1 and "its rank interval still to come" in html
    board["entries"][1] |= {"rank_low": 1, "rank_high": 2}
    html = _board_page(board["entries"], 30)
    assert 'data-role="rank-pending"' not in html and "still to come" not in html
    unranked = {**_board(), "entries": [_board()["entries"][0] | {"rank": None}]}
    assert board_table(unranked)["rows"][0]["rank_pending"] is False
