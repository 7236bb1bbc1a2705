"""`robobpp evaluate` end to end, in a subprocess like a user runs it."""

import json
import os
import subprocess
import sys
from typing import Any

import pytest

from robobpp.datasets import episode_specs
from robobpp.episode import run_episode
from robobpp.policies import load_policy


def robobpp(*args: str, env_extra: dict | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, **(env_extra or {})}
    return subprocess.run(
        [sys.executable, "-m", "robobpp.cli", *args], capture_output=True, text=True, env=env, timeout=300
    )


@pytest.mark.network
def test_evaluate_writes_results_matching_the_loop(real_data, tmp_path):
    out = tmp_path / "out.json"
    trace = tmp_path / "trace.json"
    proc = robobpp(
        "evaluate",
        "--policy",
        "dbl",
        "--dataset",
        "repetitive",
        "--setting",
        "math",
        "--groups",
        "2",
        "--json",
        str(out),
        "--trace",
        str(trace),
        env_extra={"ROBOBPP_DATA_DIR": str(real_data)},
    )
    assert proc.returncode == 0, proc.stderr
    assert "Space Utilization" in proc.stdout and "repetitive" in proc.stdout
    payload = json.loads(out.read_text())
    assert [e["episode_id"] for e in payload["episodes"]] == ["repetitive-train-000", "repetitive-train-001"]
    local = [run_episode(s, load_policy("dbl"), "math") for s in episode_specs("repetitive", groups=2)]
    for got, want in zip(payload["episodes"], local, strict=True):
        assert got["metrics"]["space_utilization"] == pytest.approx(want.metrics["space_utilization"])
        assert got["boxes_placed"] == want.boxes_placed and got["termination"] == want.termination
    occupancy = [r.metrics["occupancy"] for r in local]
    assert None not in occupancy
    mean = sum(o for o in occupancy if o is not None) / 2
    assert payload["runs"][0]["metrics"]["occupancy"] == pytest.approx(mean)
    steps = json.loads(trace.read_text())["episodes"][0]["steps"]
    assert len(steps) == len(local[0].steps) and steps[0]["placement"]["z"] == 0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--policy", "nope"], "unknown policy"),
        (["--policy", "dbl", "--dataset", "moon"], "unknown dataset"),
        (["--policy", "dbl", "--setting", "space"], "unknown setting"),
        (["--policy", "dbl", "--split", "secret"], "unknown split"),
        (["--policy", "dbl", "--groups", "0"], "--groups"),
        (["--policy", "no_such_mod:X"], "cannot import"),
    ],
)
def test_bad_arguments_exit_nonzero_with_a_clear_message(args, message):
    proc = robobpp("evaluate", *args)
    assert proc.returncode != 0
    assert message in proc.stderr + proc.stdout
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("command", [["evaluate", "--policy"], ["policy", "serve"]])
def test_module_class_policy_is_found_in_the_working_directory(tmp_path, command):
    """Like `python -m`, a participant's `mypolicy.py` beside them is importable as `mypolicy:Class`."""
    (tmp_path / "mypolicy_cwd_probe.py").write_text("class Mine:\n    pass\n")
    # -P: do not prepend the working directory, as the `robobpp` console script does not.
    proc = subprocess.run(
        [sys.executable, "-P", "-m", "robobpp.cli", *command, "mypolicy_cwd_probe:Missing"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert proc.returncode != 0
    assert "has no attribute 'Missing'" in proc.stderr, proc.stderr  # imported, unlike "cannot import"


def test_policy_failures_are_explained_under_the_table():
    """A table that says only `policy_error: 1` leaves a newcomer guessing; the first detail says why."""
    from types import SimpleNamespace

    from robobpp.cli.evaluate import failure_notes

    def result(eid: str, reason: str, detail: str) -> Any:  # stands in for an EpisodeResult
        return SimpleNamespace(episode_id=eid, termination=reason, termination_detail=detail)

    runs = {
        ("diverse", "math"): [
            result(
                "diverse-train-000", "policy_error", "refused GET /info (HTTP 401): check the shared secret"
            ),
            result(
                "diverse-train-001", "policy_error", "refused GET /info (HTTP 401): check the shared secret"
            ),
            result(
                "diverse-train-002", "no_feasible_placement", "no feasible placement for box #9 (the 10th)"
            ),
        ]
    }
    notes = failure_notes(runs)
    assert notes == [
        "policy_error in 2 episode(s), e.g. diverse-train-000: refused GET /info (HTTP 401): check the shared secret"
    ]


@pytest.mark.network
def test_jobs_give_the_same_results_in_the_same_order(real_data, tmp_path):
    env = {"ROBOBPP_DATA_DIR": str(real_data)}
    outputs = []
    for jobs in ("1", "2"):
        out = tmp_path / f"jobs{jobs}.json"
        proc = robobpp(
            "evaluate",
            "--policy",
            "hm",
            "--dataset",
            "diverse,longboard",
            "--setting",
            "math,physics",
            "--groups",
            "2",
            "--jobs",
            jobs,
            "--json",
            str(out),
            env_extra=env,
        )
        assert proc.returncode == 0, proc.stderr
        outputs.append(json.loads(out.read_text()))

    def figures(payload):
        return [
            (
                e["episode_id"],
                e["setting"],
                e["boxes_placed"],
                e["termination"],
                {k: v for k, v in e["metrics"].items() if k != "decision_time"},
            )
            for e in payload["episodes"]
        ]

    assert len(outputs[0]["episodes"]) == 8
    assert figures(outputs[0]) == figures(outputs[1])
