"""`robobpp compare`: local results scored against each other like the leaderboard."""

import json

import pytest

from robobpp.scoring import score_entries
from tests.cli.test_evaluate import robobpp


@pytest.fixture
def results(real_data, tmp_path):
    env = {"ROBOBPP_DATA_DIR": str(real_data)}
    paths = {}
    for policy, groups in (("dbl", "2"), ("random", "2"), ("hm", "1")):
        path = tmp_path / f"{policy}.json"
        proc = robobpp("evaluate", "--policy", policy, "--dataset", "diverse", "--groups", groups,
                       "--json", str(path), env_extra=env)  # fmt: skip
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
