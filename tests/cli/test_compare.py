"""`robobpp compare`: local results scored against each other like the leaderboard."""

import json
import os
import subprocess
import sys

import pytest

from robobpp.scoring.scores import score_entries
from tests.cli.test_evaluate import robobpp


@pytest.fixture
def results(real_data, tmp_path):
    env = {"ROBOBPP_DATA_DIR": str(real_data)}
    paths = {}
    for policy, groups in (("dbl", "2"), ("random", "2"), ("hm", "1")):
        path = tmp_path / f"{policy}.json"
        proc = robobpp(
            "evaluate",
            "--policy",
            policy,
            "--dataset",
            "diverse",
            "--groups",
            groups,
            "--json",
            str(path),
            env_extra=env,
        )
        assert proc.returncode == 0, proc.stderr
        paths[policy] = path
    return paths


@pytest.mark.network
def test_compare_ranks_like_the_leaderboard(results, tmp_path):
    out = tmp_path / "scored.json"
    proc = robobpp("compare", str(results["dbl"]), str(results["random"]), "--json", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "diverse · math" in proc.stdout and "score" in proc.stdout
    (board,) = json.loads(out.read_text())
    metrics = [json.loads(results[p].read_text())["runs"][0]["metrics"] for p in ("dbl", "random")]
    expected = score_entries(metrics, "math")
    by_policy = {e["policy"]: e for e in board["entries"]}
    assert by_policy["dbl"]["score"] == pytest.approx(expected[0].score)
    assert by_policy["random"]["rank"] == expected[1].rank
    assert [e["rank"] for e in board["entries"]] == sorted(e["rank"] for e in board["entries"])


@pytest.mark.network
def test_compare_refuses_results_on_different_episodes(results):
    proc = robobpp("compare", str(results["dbl"]), str(results["hm"]))
    assert proc.returncode != 0 and "ran different episodes" in proc.stderr


def test_compare_refuses_bad_input(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"runs": 3}')
    assert "give at least two" in robobpp("compare", str(bad)).stderr
    proc = robobpp("compare", str(bad), str(tmp_path / "missing.json"))
    assert proc.returncode != 0 and "not a `robobpp evaluate --json` file" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.network
def test_compare_shows_intervals_and_a_policy_against_itself_is_zero_centred(results, tmp_path):
    twin = tmp_path / "twin.json"
    twin.write_text(results["dbl"].read_text().replace('"policy": "dbl"', '"policy": "dbl-again"'))
    out = tmp_path / "self.json"
    proc = robobpp("compare", str(results["dbl"]), str(twin), "--json", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "paired difference" in proc.stdout and "no clear difference" in proc.stdout
    (board,) = json.loads(out.read_text())
    paired = board["entries"][0]["paired"]["differences"]
    for key in ("space_utilization", "occupancy", "stable"):
        assert paired[key]["difference"] == 0 and paired[key]["low"] == 0 == paired[key]["high"]
    entry = board["entries"][0]
    low, high = entry["intervals"]["space_utilization"]
    assert low <= entry["metrics"]["space_utilization"] <= high and entry["rank_ci"] == [1, 1]


@pytest.mark.network
def test_evaluate_exits_3_when_every_episode_is_a_policy_failure(real_data, tmp_path):
    (tmp_path / "garbage.py").write_text(
        "from robobpp.core import Action\n\n\nclass Garbage:\n    name = 'garbage'\n\n"
        "    def reset(self, info):\n        pass\n\n    def act(self, obs):\n        return Action(float('nan'), 0.0, 0)\n"
    )
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "robobpp.cli",
            "evaluate",
            "--policy",
            "garbage:Garbage",
            "--dataset",
            "repetitive",
            "--groups",
            "2",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
        env={**os.environ, "ROBOBPP_DATA_DIR": str(real_data)},
    )
    assert proc.returncode == 3, proc.stderr
    assert "every episode ended in a policy failure" in proc.stderr and "invalid_action in 2" in proc.stderr
