"""`robobpp reproduce` and `robobpp evaluate --protocol`, end to end in a subprocess like a user runs them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from robobpp.datasets import episode_specs
from robobpp.policies import load_policy
from robobpp.replay import run_paper_protocol
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
    local = [run_paper_protocol(s, load_policy("dbl"), ["physics"])["physics"] for s in specs]
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
