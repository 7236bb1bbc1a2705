"""`robobpp reproduce` and `robobpp evaluate --protocol`, end to end in a subprocess like a user runs them."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from robobpp.datasets import episode_specs
from robobpp.episode import EpisodeResult
from robobpp.policies import load_policy
from robobpp.replay import run_paper_loop
from robobpp.reproduction import EXPECTED
from tests.cli.test_evaluate import robobpp


@pytest.mark.network
def test_reproduce_one_group_end_to_end_and_merge(real_data: Path, tmp_path: Path) -> None:
    env = {"ROBOBPP_DATA_DIR": str(real_data)}
    out = tmp_path / "r.json"
    proc = robobpp(
        "reproduce",
        "--dataset",
        "diverse",
        "--setting",
        "math,physics",
        "--policies",
        "dbl,lsah",
        "--groups",
        "1",
        "--json",
        str(out),
        env_extra=env,
    )
    assert proc.returncode == 0, proc.stderr
    assert "Physics Pack · ours vs the paper" in proc.stdout and "protocol paper" in proc.stdout
    assert "Spearman" in proc.stdout and "0.257" in proc.stdout  # the paper's DBL, Diverse, Physics
    data = json.loads(out.read_text())
    assert data["protocol"] == "paper" and data["groups"] == {"diverse": 1}
    episodes = {(e["setting"], e["policy"]): e for e in data["episodes"]}
    assert set(episodes) == {(s, p) for s in ("math", "physics") for p in ("dbl", "lsah")}
    assert (
        episodes[("physics", "dbl")]["protocol"] == "paper"
        and episodes[("math", "dbl")]["protocol"] == "closed"
    )
    cells = {(c["setting"], c["policy"], c["metric"]): c for c in data["comparison"]["cells"]}
    cell = cells[("physics", "dbl", "space_utilization")]
    assert cell["paper"] == 0.257 and cell["table"] == "tab:deli setting12"
    assert cell["ours"] == pytest.approx(episodes[("physics", "dbl")]["metrics"]["space_utilization"])
    assert ("math", "dbl", "local_stability") not in cells  # not a Math Pack metric
    # The same table again from the file, in Markdown; the same file twice is refused as overlapping.
    again = robobpp("reproduce", "--merge", str(out), "--markdown", "--metrics", "space_utilization")
    assert again.returncode == 0, again.stderr
    assert "**Physics Pack · Space Utilization**" in again.stdout and "| DBL | 0.257 |" in again.stdout
    assert "Occupancy" not in again.stdout
    twice = robobpp("reproduce", "--merge", str(out), "--merge", str(out))
    assert twice.returncode != 0 and "overlapping runs" in twice.stderr


@pytest.mark.network
def test_evaluate_protocol_reaches_the_json(real_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "e.json"
    # two worker processes: each runs a group's Math plan and its replay
    proc = robobpp(
        "evaluate",
        "--policy",
        "dbl",
        "--dataset",
        "diverse",
        "--setting",
        "physics",
        "--groups",
        "2",
        "--protocol",
        "paper",
        "--jobs",
        "2",
        "--json",
        str(out),
        env_extra={"ROBOBPP_DATA_DIR": str(real_data)},
    )
    assert proc.returncode == 0, proc.stderr
    assert "protocol paper" in proc.stdout
    data = json.loads(out.read_text())
    assert data["protocol"] == "paper" and [r["protocol"] for r in data["runs"]] == ["paper"]
    # the Math plan was run but Math Pack was not asked for: only the replays are reported
    assert [(e["setting"], e["protocol"]) for e in data["episodes"]] == [("physics", "paper")] * 2
    specs = episode_specs("diverse", groups=2)
    local = [run_paper_loop(s, load_policy("dbl"), ["physics"])["physics"] for s in specs]
    for got, want in zip(data["episodes"], local, strict=True):
        assert got["episode_id"] == want.episode_id and got["termination"] == want.termination
        assert got["boxes_placed"] == want.boxes_placed
        assert got["metrics"]["space_utilization"] == pytest.approx(want.metrics["space_utilization"])
    # `robobpp compare` never ranks a closed-loop run against a paper-protocol one: two boards
    closed = tmp_path / "c.json"
    proc = robobpp(
        "evaluate",
        "--policy",
        "dbl",
        "--dataset",
        "diverse",
        "--setting",
        "physics",
        "--groups",
        "2",
        "--json",
        str(closed),
        env_extra={"ROBOBPP_DATA_DIR": str(real_data)},
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(closed.read_text())["protocol"] == "closed"
    boards = tmp_path / "boards.json"
    proc = robobpp("compare", str(out), str(closed), "--json", str(boards))
    assert proc.returncode == 0, proc.stderr
    assert "diverse · physics · protocol paper" in proc.stdout
    assert sorted((b["protocol"], len(b["entries"])) for b in json.loads(boards.read_text())) == [
        ("closed", 1),
        ("paper", 1),
    ]


def _episode(policy: str, group: int, utilization: float, occupancy: float, seconds: float) -> dict:
    """A Math Pack episode of the repetitive dataset as `robobpp reproduce --json` writes one (no trace)."""
    result = EpisodeResult(
        episode_id=f"repetitive-train-{group}",
        dataset="repetitive",
        split="train",
        group=group,
        setting="math",
        policy=policy,
        seed=0,
        boxes_total=20,
        boxes_placed=18,
        termination="no_feasible",
        termination_detail="",
        metrics={"space_utilization": utilization, "occupancy": occupancy, "decision_time": seconds},
        counters={},
        container={"length": 1.2, "width": 1.0, "height": 1.5},
    )
    return result.to_dict(trace=False)


def test_merge_to_markdown_says_what_is_expected(tmp_path: Path) -> None:
    """From a hand-made --json file: why each metric differs, Decision Time not compared, the score comparison
    and the paper's other methods as paper-reported rows."""
    figures = {"dbl": (0.6, 0.9, 0.01), "hm": (0.5, 1.0, 0.02), "lsah": (0.7, 0.8, 0.03)}
    episodes = [_episode(p, g, *f) for p, f in figures.items() for g in (0, 1)]
    path = tmp_path / "r.json"
    path.write_text(json.dumps({"protocol": "paper", "split": "train", "seed": 0, "episodes": episodes}))
    proc = robobpp("reproduce", "--merge", str(path), "--markdown")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "groups repetitive 2" in out and "**Math Pack · Space Utilization**" in out
    utilization = out.split("**Math Pack · Space Utilization**")[1].split("**Math Pack · Occupancy**")[0]
    assert EXPECTED["space_utilization"].why in utilization
    assert f"({EXPECTED['space_utilization'].doc})" in utilization
    # 0.6, 0.5, 0.7 against the paper's 0.617, 0.579, 0.619: the same order
    assert "| **Spearman** |  | 1.00 |  |" in utilization
    for method in ("AR2L", "TAP-Net++", "CDRL", "PackE"):  # the paper's figure, nothing of ours
        assert re.search(
            rf"^\| {re.escape(method)} \(paper-reported\) \| \d\.\d{{3}} \| – \| – \|$", utilization, re.M
        )
    timing = out.split("**Math Pack · Decision Time**")[1].split("**Math Pack · Score")[0]
    assert "| **Spearman** |  | not compared |  |" in timing and EXPECTED["decision_time"].why in timing
    # ours: 0.5, 0.26/0.86, 0.6/0.86 (as in tests/reproduction); the paper's figures: Space Utilization 0.617,
    # 0.579, 0.619 and Occupancy 0.911, 0.960, 0.908 min–max normalised
    score = out.split("**Math Pack · Score (Decision Time left out)**")[1]
    su = [(0.617 - 0.579) / 0.040, 0.0, 1.0]
    occ = [(0.911 - 0.908) / 0.052, 1.0, 0.0]
    paper = [(0.60 * u + 0.26 * o) / 0.86 for u, o in zip(su, occ, strict=True)]
    assert f"| DBL | 0.500 | {paper[0]:.3f} |" in score and f"| HM | 0.302 | {paper[1]:.3f} |" in score
    assert f"| LSAH | 0.698 | {paper[2]:.3f} |" in score and "| **Spearman** |  | 1.00 |" in score
    assert "AR2L" not in score
    # the terminal tables say the same
    terminal = robobpp("reproduce", "--merge", str(path))
    assert terminal.returncode == 0, terminal.stderr
    assert (
        "not compared" in terminal.stdout and "Math Pack · Score (Decision Time left out)" in terminal.stdout
    )
    assert "AR2L (paper-reported)" in terminal.stdout and "docs/benchmark.md#metrics" in terminal.stdout
    data = path.with_name("again.json")
    assert robobpp("reproduce", "--merge", str(path), "--json", str(data)).returncode == 0
    (scores,) = json.loads(data.read_text())["comparison"]["scores"]
    assert scores["policies"] == ["dbl", "hm", "lsah"] and scores["paper"] == pytest.approx(paper)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["evaluate", "--policy", "dbl", "--protocol", "open"], "unknown protocol 'open'"),
        (
            ["evaluate", "--policy", "dbl", "--setting", "math", "--protocol", "paper"],
            "add --setting physics",
        ),
        (["reproduce", "--protocol", "open"], "unknown protocol 'open'"),
        (["reproduce", "--policies", "nope"], "unknown policy nope"),
        (["reproduce", "--metrics", "speed"], "unknown metric speed"),
    ],
)
def test_bad_protocol_arguments_fail_clearly(args: list[str], message: str) -> None:
    proc = robobpp(*args)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert message in proc.stderr and "Traceback" not in proc.stderr
