"""What a researcher publishes from a local run: `robobpp --version`, provenance on every result, the board's
95 % intervals beside each figure of `robobpp evaluate`, per-group CSV and Markdown/LaTeX tables."""

import csv
import io
import json
import os
import re
import subprocess
from pathlib import Path

import pytest

import robobpp
from robobpp import provenance
from robobpp.datasets.private import build_private, load_private
from robobpp.datasets.sampling import SAMPLER_VERSION
from robobpp.export import latex_escape
from robobpp.scoring.scores import ANCHORS_VERSION
from robobpp.sim import MATH_RULES_VERSION
from tests.cli.test_evaluate import robobpp as run_cli

ROOT = Path(__file__).resolve().parents[2]


def test_version_names_the_release_and_the_checkouts_commit():
    proc = run_cli("--version")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"robobpp {robobpp.__version__}")
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode == 0:  # run from a checkout (CI, a clone): the commit is named
        assert f"(commit {head.stdout.strip()}" in proc.stdout


def test_the_datasets_fingerprint_ignores_when_and_how_the_cache_was_written(tmp_path, monkeypatch):
    """Two caches converted from the same wheel agree, though their creation times and archives differ."""
    from robobpp.datasets.cache import CACHE_FORMAT, CONVERTED_DIR

    def cache(root: Path, created: str, archive_sha: str, wheel_sha: str) -> str | None:
        (root / CONVERTED_DIR).mkdir(parents=True)
        manifest = {
            "format": CACHE_FORMAT,
            "created": created,
            "source": {"sha256": wheel_sha},
            "files": {"diverse.npz": {"sha256": archive_sha}},
            "datasets": {"diverse": {"boxes": 3}},
        }
        (root / CONVERTED_DIR / "manifest.json").write_text(json.dumps(manifest))
        return provenance.datasets_manifest_sha256(root)

    a = cache(tmp_path / "a", "2026-01-01", "aa", "wheel")
    b = cache(tmp_path / "b", "2026-02-02", "bb", "wheel")
    c = cache(tmp_path / "c", "2026-01-01", "aa", "another wheel")
    assert a == b and a is not None and len(a) == 64 and c != a
    assert provenance.datasets_manifest_sha256(tmp_path / "none") is None


def test_spec_files_and_the_private_set_keep_the_sampler_version(real_data, tmp_path):
    build_private(tmp_path, seed=7, groups=2, datasets=["diverse"])
    specs = load_private("diverse", tmp_path)
    assert {s.sampler_version for s in specs} == {SAMPLER_VERSION}


@pytest.fixture
def evaluated(real_data, tmp_path):
    out, table = tmp_path / "dbl.json", tmp_path / "dbl.csv"
    proc = run_cli(
        "evaluate",
        "--policy",
        "dbl",
        "--dataset",
        "diverse",
        "--groups",
        "5",
        "--seed",
        "3",
        "--json",
        str(out),
        "--csv",
        str(table),
        env_extra={"ROBOBPP_DATA_DIR": str(real_data)},
    )
    assert proc.returncode == 0, proc.stderr
    return proc, json.loads(out.read_text()), table


@pytest.mark.network
def test_evaluate_records_its_provenance(evaluated, real_data):
    _proc, payload, _csv = evaluated
    got = payload["provenance"]
    assert list(got) == list(provenance.FIELDS)
    assert got["robobpp"] == robobpp.__version__ and got["commit"] == provenance.git_commit()
    assert got["datasets_manifest_sha256"] == provenance.datasets_manifest_sha256(real_data)
    assert got["machine"] == provenance.machine()  # Decision Time's machine
    assert got["physics"] is None  # Math Pack: no physics
    assert (got["math_rules"], got["sampler"], got["anchors"]) == (
        MATH_RULES_VERSION,
        SAMPLER_VERSION,
        ANCHORS_VERSION,
    )
    assert (got["protocol"], got["split"], got["seed"], got["groups"]) == ("closed", "train", 3, 5)
    for e in payload["episodes"]:  # each episode carries what produced it
        assert (e["rules_version"], e["sampler_version"], e["protocol"]) == (
            MATH_RULES_VERSION,
            SAMPLER_VERSION,
            "closed",
        )


@pytest.mark.network
def test_evaluate_prints_and_writes_the_boards_intervals(evaluated, tmp_path):
    """Beside each figure its 95 % bootstrap interval: the same numbers the board and `compare` compute."""
    proc, payload, _csv = evaluated
    (run,) = payload["runs"]
    assert payload["confidence"] == 0.95 and payload["resamples"] == 1000
    for key in ("space_utilization", "occupancy", "decision_time"):
        low, high = run["intervals"][key]
        assert low <= run["metrics"][key] <= high and low < high
    low, high = run["stable_interval"]
    assert low <= run["stable"] <= high
    su = run["metrics"]["space_utilization"]
    s_low, s_high = run["intervals"]["space_utilization"]
    assert f"{su:.4f} [{s_low:.4f}, {s_high:.4f}]" in proc.stdout
    assert "bootstrap 95 % interval over groups" in proc.stdout
    # the board's code: `compare` (score_board over the same groups) gives each entry the same intervals
    twin = tmp_path / "twin.json"
    twin.write_text(json.dumps({**payload, "policy": "dbl-again"}))
    source = tmp_path / "source.json"
    source.write_text(json.dumps(payload))
    scored = tmp_path / "scored.json"
    assert run_cli("compare", str(source), str(twin), "--json", str(scored)).returncode == 0
    (board,) = json.loads(scored.read_text())
    for entry in board["entries"]:  # equal up to the summation order of a matrix product
        assert entry["intervals"] == {k: pytest.approx(v, rel=1e-12) for k, v in run["intervals"].items()}
        assert entry["stable_ci"] == pytest.approx(run["stable_interval"], rel=1e-12)


@pytest.mark.network
def test_per_group_csv_and_summary_tables(evaluated, tmp_path):
    _proc, payload, table = evaluated
    rows = list(csv.DictReader(io.StringIO(table.read_text())))
    assert [int(r["group"]) for r in rows] == [0, 1, 2, 3, 4]
    for row, episode in zip(rows, payload["episodes"], strict=True):
        assert float(row["space_utilization"]) == episode["metrics"]["space_utilization"]  # full precision
        assert row["episode_id"] == episode["episode_id"] and row["termination"] == episode["termination"]
        assert (row["math_rules"], row["sampler"], row["seed"], row["groups"]) == (
            MATH_RULES_VERSION,
            SAMPLER_VERSION,
            "3",
            "5",
        )
        assert row["datasets_manifest_sha256"] == payload["provenance"]["datasets_manifest_sha256"]
    source = tmp_path / "run.json"
    source.write_text(json.dumps(payload))
    (run,) = payload["runs"]
    low, high = run["intervals"]["space_utilization"]
    figure = f"{run['metrics']['space_utilization']:.4f} [{low:.4f}, {high:.4f}]"
    md = run_cli("export", str(source), "--format", "md")
    assert md.returncode == 0, md.stderr
    boxes = f"{run['boxes_placed']:.1f}"
    assert (
        f"| diverse | math | 5 | {boxes} | {figure}" in md.stdout
        and f"sampler {SAMPLER_VERSION}" in md.stdout
    )
    tex = tmp_path / "run.tex"
    assert run_cli("export", str(source), "--format", "latex", "--out", str(tex)).returncode == 0
    text = tex.read_text()
    compact = f"{run['metrics']['space_utilization']:.3f}\\\\\\scriptsize {low:.3f}--{high:.3f}"
    assert text.startswith("\\begin{table}") and "\\toprule" in text and compact in text
    assert "datasets\\_manifest\\_sha256" in text and "95 \\% interval" in text
    again = run_cli("export", str(source), "--format", "csv")
    assert again.stdout == table.read_text()
    bad = run_cli("export", str(source), "--format", "docx")
    assert bad.returncode == 2 and "unknown format 'docx'" in bad.stderr


@pytest.mark.network
def test_a_run_says_its_lookahead_and_compare_keeps_lookaheads_apart(evaluated, real_data, tmp_path):
    """A policy shown the next boxes solved another task: its lookahead is in the provenance, the per-group CSV
    and the tables, and `compare` refuses to rank it beside a lookahead-0 run of the same episodes."""
    _proc, plain, _csv = evaluated
    out, table = tmp_path / "seer.json", tmp_path / "seer.csv"
    proc = run_cli(
        "evaluate",
        "--policy",
        "dbl",
        "--dataset",
        "diverse",
        "--groups",
        "5",
        "--seed",
        "3",
        "--lookahead",
        "3",
        "--json",
        str(out),
        "--csv",
        str(table),
        env_extra={"ROBOBPP_DATA_DIR": str(real_data)},
    )
    assert proc.returncode == 0, proc.stderr
    payload = json.loads(out.read_text())
    assert payload["lookahead"] == payload["provenance"]["lookahead"] == 3
    assert plain["provenance"]["lookahead"] == 0
    assert "lookahead 3" in proc.stdout  # the table's caption
    assert {r["lookahead"] for r in csv.DictReader(io.StringIO(table.read_text()))} == {"3"}
    md = run_cli("export", str(out), "--format", "md")
    assert md.returncode == 0 and "lookahead 3" in md.stdout
    source = tmp_path / "plain.json"
    source.write_text(json.dumps(plain))
    refused = run_cli("compare", str(source), str(out))
    assert refused.returncode != 0 and "not comparable" in refused.stderr and "lookahead" in refused.stderr


def test_export_refuses_what_is_not_an_evaluate_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"runs": [{"dataset": 1}]}')
    proc = run_cli("export", str(bad))
    assert proc.returncode == 2 and "not a `robobpp evaluate --json` file" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_latex_escapes_what_tex_would_read_as_commands():
    assert latex_escape("a_b & 50 % #1 {x} ~^\\ ↑") == (
        r"a\_b \& 50 \% \#1 \{x\} \textasciitilde{}\textasciicircum{}\textbackslash{} $\uparrow$"
    )


class _Named:
    """A served policy that says who it is."""

    name = "lowest-first"
    version = "2.1"

    def __init__(self) -> None:
        from robobpp.policies.dbl import DBL

        self._dbl = DBL()

    def act(self, obs):
        return self._dbl.act(obs)


@pytest.mark.network
def test_a_served_policy_is_named_by_its_info_not_its_url(real_data, tmp_path):
    """`serve(policy)` answers the policy's name and version in /info (it said "0"), and `evaluate` labels
    the results with them (it used the URL)."""
    import httpx

    from robobpp.client.serve import BackgroundServer, create_policy_app

    with BackgroundServer(create_policy_app(_Named())) as server:
        info = httpx.get(server.url + "/info").json()
        assert (info["name"], info["version"]) == ("lowest-first", "2.1")
        out = tmp_path / "served.json"
        proc = run_cli(
            "evaluate",
            "--policy",
            server.url,
            "--dataset",
            "diverse",
            "--groups",
            "1",
            "--json",
            str(out),
            env_extra={"ROBOBPP_DATA_DIR": str(real_data)},
        )
    assert proc.returncode == 0, proc.stderr
    payload = json.loads(out.read_text())
    assert payload["policy"] == "lowest-first 2.1" and server.url not in proc.stdout
    assert {e["policy"] for e in payload["episodes"]} == {"lowest-first 2.1"}
    assert "lowest-first 2.1" in proc.stdout
    with BackgroundServer(create_policy_app(_Named(), name="given", version="3")) as server:
        assert httpx.get(server.url + "/info").json()["version"] == "3"


@pytest.mark.network
def test_compare_refuses_results_of_different_versions(evaluated, tmp_path):
    """As a board keeps versions apart, `compare` refuses two runs whose episodes ran other Math rules."""
    _proc, payload, _csv = evaluated
    older = {
        **payload,
        "policy": "older",
        "episodes": [{**e, "rules_version": "0"} for e in payload["episodes"]],
    }
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(payload))
    b.write_text(json.dumps(older))
    proc = run_cli("compare", str(a), str(b))
    assert proc.returncode == 2 and "math_rules version 0" in proc.stderr and "not comparable" in proc.stderr
    legacy = {
        **payload,
        "policy": "legacy",
        "episodes": [{k: v for k, v in e.items() if k != "rules_version"} for e in payload["episodes"]],
    }
    b.write_text(json.dumps(legacy))
    assert run_cli("compare", str(a), str(b)).returncode == 0  # a file from before versions: not checked


def test_grid_and_board_csvs_print_every_figure_at_one_precision():
    """The grid CSV printed a Mean as 0.5806950457624445 beside scores of 12 decimals: every figure of a
    board's or the grid's CSV has at most 12 decimals (the precision scores are ranked at)."""
    from robobpp.export import board_csv, grid_csv

    row = {
        "status": "ranked",
        "rank": 1,
        "rank_low": 1,
        "rank_high": 2,
        "submission_id": 7,
        "name": "a",
        "participant": "p",
        "baseline": False,
        "mean": 0.5806950457624445,
        "mean_low": 1 / 3,
        "mean_high": 0.7,
        "stable": -1e-17,
        "stable_low": 0.1,
        "stable_high": 0.9,
        "cells": {"math/diverse": {"score": 2 / 3, "rank": 1}},
    }
    grid = {"track": "private", "settings": ["math"], "datasets": ["diverse"], "rows": [row]}
    line = dict(zip(*csv.reader(io.StringIO(grid_csv(grid))), strict=True))
    assert (
        line["mean"] == "0.580695045762" and line["mean_low"] == "0.333333333333" and line["stable"] == "0.0"
    )
    assert line["math/diverse_score"] == "0.666666666667" and line["rank"] == "1"
    entry = {
        "rank": 1,
        "submission_id": 7,
        "name": "a",
        "participant": "p",
        "baseline": False,
        "score": 1 / 7,
        "metrics": {"space_utilization": 0.5806950457624445},
        "intervals": {"space_utilization": [0.1, 2 / 3]},
    }
    board = {"dataset": "diverse", "setting": "math", "metrics": ["space_utilization"], "entries": [entry]}
    line = dict(zip(*csv.reader(io.StringIO(board_csv(board))), strict=True))
    assert line["score"] == "0.142857142857" and line["space_utilization"] == "0.580695045762"
    assert line["space_utilization_high"] == "0.666666666667"


def test_provenance_names_the_machine_but_boards_do_not_split_on_it(tmp_path):
    """Decision Time is wall-clock: every result names the CPU model and its logical cores (it named none)."""
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nmodel name\t: AMD EPYC  7763 64-Core Processor\nflags\t: fpu\n")
    assert provenance.cpu_model(cpuinfo) == "AMD EPYC 7763 64-Core Processor"
    assert provenance.cpu_model(tmp_path / "none")  # no /proc: what platform knows
    here = provenance.environment()["machine"]
    assert here == provenance.machine() and f"({os.cpu_count()} logical cores)" in here
    assert "machine" in provenance.FIELDS and "machine" not in provenance.recorded_rules()
    assert f"machine {here}" in provenance.one_line(provenance.environment())


def _run(dataset: str, setting: str, terminations: dict[str, int], boxes: float) -> dict:
    return {
        "dataset": dataset,
        "setting": setting,
        "protocol": "closed",
        "episodes": sum(terminations.values()),
        "boxes_placed": boxes,
        "metrics": {"space_utilization": 0.31944, "decision_time": 0.0011},
        "intervals": {"space_utilization": [0.23931, 0.39114], "decision_time": [0.00085, 0.0014]},
        "stable": 0.5,
        "stable_interval": [0.4, 0.6],
        "terminations": terminations,
    }


#: A run of two datasets, listed as a user may ask for them (longboard first), with the paper's order mixed up.
RUN = {
    "policy": "mine",
    "confidence": 0.95,
    "provenance": {"robobpp": "0.1.0", "machine": "AMD EPYC 7763 (2 logical cores)", "groups": 30},
    "runs": [
        _run("longboard", "math", {"no_feasible_placement": 12, "collapse": 18}, 27.13),
        _run("repetitive", "math", {"completed": 30}, 80.0),
    ],
    "episodes": [
        {"dataset": d, "setting": s, "split": "train", "group": 0, "episode_id": f"{d}-{s}"}
        | {"termination": "completed", "boxes_placed": 1, "boxes_total": 1}
        for d, s in (
            ("diverse", "physics"),
            ("longboard", "math"),
            ("diverse", "math"),
            ("repetitive", "math"),
        )
    ],
}


def test_a_runs_tables_report_boxes_placed_and_how_episodes_ended():
    """docs/reporting.md asks for boxes placed and the terminations: the tables had neither."""
    from robobpp.export import render_run

    md = render_run(RUN, "md")
    assert "| boxes placed |" in md and "| terminations |" in md
    assert "| longboard | math | 30 | 27.1 | " in md and md.rstrip().count("collapse 18, no place 12 |") == 1
    assert "| repetitive | math | 30 | 80.0 | " in md and "done 30 |" in md
    assert "machine AMD EPYC 7763 (2 logical cores)" in md
    tex = render_run(RUN, "latex")
    assert "27.1" in tex and r"\scriptsize collapse 18" in tex and r"\scriptsize no place 12" in tex
    assert "machine AMD EPYC 7763 (2 logical cores)" in tex


def test_rows_follow_the_papers_tables_repetitive_diverse_longboard_then_math_physics_execution():
    """The per-group CSV ordered rows diverse, longboard, repetitive (by name); the tables as asked."""
    from robobpp.export import render_run

    rows = list(csv.DictReader(io.StringIO(render_run(RUN, "csv"))))
    assert [(r["dataset"], r["setting"]) for r in rows] == [
        ("repetitive", "math"),
        ("diverse", "math"),
        ("diverse", "physics"),
        ("longboard", "math"),
    ]
    assert {r["machine"] for r in rows} == {"AMD EPYC 7763 (2 logical cores)"}
    md = render_run(RUN, "md")
    assert md.index("| repetitive |") < md.index("| longboard |")


def test_the_latex_layout_fits_a_column_and_wide_spans_two():
    """Nine columns of "0.3194 [0.2393, 0.3911]" did not fit a column: three decimals, the interval in small
    type under its figure, no bracketed interval; a unit figure keeps significant figures; --wide: table*."""
    from robobpp.export import render_run

    tex = render_run(RUN, "latex")
    assert tex.startswith("\\begin{table}\n") and tex.rstrip().endswith("\\end{table}")
    assert not re.search(r"\[\d+\.\d+, \d+\.\d+\]", tex) and "0.3194" not in tex
    assert "0.319\\\\\\scriptsize 0.239--0.391" in tex
    assert "0.00110\\\\\\scriptsize 0.00085--0.00140" in tex  # seconds: significant figures, not 0.001
    assert "makecell" not in tex and "\\begin{tabular}[b]{@{}r@{}}Space\\\\Utilization $\\uparrow$" in tex
    assert "Brackets" not in tex and "Small type under a figure: its bootstrap 95 \\% interval" in tex
    wide = render_run(RUN, "latex", wide=True)
    assert wide.startswith("\\begin{table*}\n") and wide.rstrip().endswith("\\end{table*}")
    assert "[0.2393, 0.3911]" in render_run(RUN, "md")  # Markdown keeps the one-line form


def test_a_boards_caption_names_its_server_and_date():
    """A relative score is quotable only with its board: server and date (the caption had neither)."""
    from datetime import date

    from robobpp.export import render_board, render_grid

    board = {
        "dataset": "diverse",
        "setting": "math",
        "track": "private",
        "metrics": ["space_utilization"],
        "entries": [
            {
                "rank": 1,
                "name": "a",
                "participant": "p",
                "baseline": False,
                "score": 1.0,
                "score_low": 0.9,
                "score_high": 1.0,
                "metrics": {"space_utilization": 0.5},
                "intervals": {"space_utilization": [0.4, 0.6]},
            }
        ],
    }
    server = "https://alice:s3cret@bpp.example.org/?x=1"
    tex = render_board(board, "latex", server=server, exported=date(2026, 3, 1))
    caption = tex[tex.index("\\caption{") :]
    assert "https://bpp.example.org" in caption and "2026-03-01 (UTC)" in caption and "s3cret" not in tex
    grid = {"track": "private", "settings": ["math"], "datasets": ["diverse"], "rows": []}
    assert "https://bpp.example.org" in render_grid(grid, "md", server=server)


def test_the_ending_labels_cover_every_termination_reason():
    from robobpp.episode import TERMINATION_REASONS, TERMINATION_SHORT
    from robobpp.export import endings

    assert set(TERMINATION_SHORT) == set(TERMINATION_REASONS)
    assert endings({"completed": 1, "collapse": 18, "no_feasible_placement": 12, "worker_lost": 0}) == (
        "collapse 18, no place 12, done 1"
    )
