"""Determinism across processes: a fresh interpreter (another hash seed, nothing warmed up) gives exactly the
figures this process gives for the same episode, after this process has run a different one first."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from robobpp.datasets.synthetic import synthetic_episode_specs
from robobpp.episode import run_episode
from robobpp.policies import load_policy

SCRIPT = """
import json, sys
from robobpp.datasets.synthetic import synthetic_episode_specs
from robobpp.episode import run_episode
from robobpp.policies import load_policy
spec = synthetic_episode_specs(2, seed=11, container="repetitive")[1]
spec = type(spec)(**{**{f: getattr(spec, f) for f in spec.__dataclass_fields__}, "boxes": spec.boxes[:BOXES]})
print(json.dumps(run_episode(spec, load_policy("dbl"), sys.argv[1]).to_dict()))
"""


def _figures(result: dict) -> dict:
    """Everything but wall-clock time."""
    result = json.loads(json.dumps(result))
    result["metrics"].pop("decision_time")
    for step in result["steps"]:
        step.pop("decision_time")
        step["extra"].pop("planning_time_s", None)
    return result


@pytest.mark.slow
@pytest.mark.parametrize(("setting", "boxes"), [("physics", 25), ("execution", 8)])
def test_fresh_process_gives_identical_figures(setting: str, boxes: int) -> None:
    specs = synthetic_episode_specs(2, seed=11, container="repetitive")
    run_episode(specs[0], load_policy("dbl"), setting)  # a different episode first: no state may leak
    spec = specs[1]
    spec = type(spec)(
        **{**{f: getattr(spec, f) for f in spec.__dataclass_fields__}, "boxes": spec.boxes[:boxes]}
    )
    here = run_episode(spec, load_policy("dbl"), setting).to_dict()
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT.replace("BOXES", str(boxes)), setting],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    there = json.loads(proc.stdout.strip().splitlines()[-1])
    assert here["boxes_placed"] >= 3
    assert _figures(there) == _figures(here)
